"""The smooth display's steep patches (``steep``, mi_plugins.solution.steep): where the
field fitted to the patch values departs from a patch's own value, the display gathers."""
import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.verify.conformance import runner
from test_darkness import panel_on_floor, without_the_patch_fallback

pytestmark = pytest.mark.skipif(not mi.variant(), reason="needs a Mitsuba variant")

#: the panel 5 cm above the floor at 64 px: rows 44-47 (central columns) are the shadowed
#: floor just in front of the strip that the light passing under the panel lights
STRIP = np.s_[44:48, 24:40]


def panel_bands(integrator, spp, runs, seed, bands):
    """{name: (mean, standard error)} over ``runs`` renders of the panel 5 cm above the
    floor at 64 px, of each of ``bands`` ({name: pixel slice})."""
    scene = panel_on_floor(lift=0.05, resolution=64)
    images = runner.render_runs(scene, integrator, spp, [budget.seed(seed) * 1000 + r for r in range(runs)])[0]
    out = {}
    for name, rows in bands.items():
        means = images[(slice(None),) + rows][..., :3].mean(axis=(1, 2, 3))
        out[name] = means.mean(), means.std(ddof=1) / np.sqrt(runs)
    return out


def _band(integrator, spp, runs, seed):
    return panel_bands(integrator, spp, runs, seed, {"strip": STRIP})["strip"]


@pytest.fixture(scope="module")
def strip_reference():
    """``path``'s mean over the strip's rows and its standard error (one render for the module)."""
    return _band({"type": "path"}, 2048, 8, 50)


def test_steep_patches_gather_beside_the_lit_strip(strip_reference):
    """``ray_bundle``'s smooth display with ``steep=0.5`` matches ``path`` on the shadowed
    floor beside the lit strip (-12.8 %, z -1.9 measured); test of the test: without it
    (``steep=0``, the default) the field carries the strip's light into the shadow, +26 %
    (z +5.9 at 64 spp; +588 % before the field's limiter)."""
    ref, ref_se = strip_reference
    settings = {"type": "ray_bundle", "iterations": 24, "display": "smooth"}
    mean, se = _band(dict(settings, steep=0.5), 16, 8, 55)
    budget.close(mean, ref, np.hypot(se, ref_se), what="ray_bundle smooth display with steep beside the strip / path")
    bad, bad_se = _band(dict(settings, steep=0.0), 64, 8, 55)
    assert bad - ref > 4 * np.hypot(bad_se, ref_se), (bad, ref, bad_se, ref_se)


def test_the_limited_smooth_display_beside_the_lit_strip(strip_reference, monkeypatch):
    """``qmc_lighttrace``'s default smooth display matches ``path`` on the shadowed floor
    beside the lit strip: the field's limiter (mi_plugins.solution.limiter) keeps the
    vertices there within their patches' values (+2.6 %, z +0.2; +6.0 %, z +0.9 at 16 x
    128 spp). Test of the test: without the limiter the planes fitted across the strip's
    edge carry its light into the shadow, +547 % (z +37)."""
    from mi_plugins.solution import limiter
    ref, ref_se = strip_reference
    settings = {"type": "qmc_lighttrace", "samples": 100000, "display": "smooth"}
    mean, se = _band(settings, 16, 8, 55)
    budget.close(mean, ref, np.hypot(se, ref_se), what="limited smooth display beside the strip / path")
    monkeypatch.setattr(limiter, "limited", lambda out, flat, groups: out)
    bad, bad_se = _band(settings, 16, 8, 55)
    assert bad > 2.0 * ref and bad - ref > 4 * np.hypot(bad_se, ref_se), (bad, ref, bad_se, ref_se)


@pytest.mark.xfail(strict=True, reason="known defect: ray_bundle's default smooth display (steep off) carries the "
                   "lit strip's light into the shadowed floor beside it: +26 % (z +5.9, 8 x 64 spp; +34 %, z +12 at "
                   "16 x 128 spp; +588 % before the field's limiter)")
def test_the_default_smooth_display_beside_the_lit_strip(strip_reference):
    ref, ref_se = strip_reference
    mean, se = _band({"type": "ray_bundle", "iterations": 24, "display": "smooth"}, 64, 8, 55)
    budget.close(mean, ref, np.hypot(se, ref_se), what="default smooth display beside the strip / path")


def _image_mean(scene, integrator, spp, runs, seed):
    images = runner.render_runs(scene, integrator, spp, [budget.seed(seed) * 1000 + r for r in range(runs)])[0]
    means = images[..., :3].mean(axis=(1, 2, 3))
    return means.mean(), means.std(ddof=1) / np.sqrt(runs)


def test_steep_patches_are_decided_on_a_second_solve(monkeypatch):
    """Which patches gather does not follow the displayed values' noise: ``qmc_lighttrace``
    at 20 000 paths with ``steep=0.5`` keeps the image mean of ``cornell_mesh`` (-0.11 %,
    z -2.5 in the conformance suite's runs; -0.03 .. -0.08 %, |z| <= 1.4 here over three
    seed sets); the second solve runs once per solution and leaves the integrator's state
    as the first solve left it. Test of the test: deciding on the displayed solution itself
    raises the mean (+0.43 .. +0.59 %, z 7.1-12 over the same seed sets)."""
    from mi_plugins.solution import integrator as solution_integrator
    from mi_plugins.verify.conformance import scene_library
    scene = scene_library.cornell_mesh(16)
    settings = {"type": "qmc_lighttrace", "samples": 20000, "display": "smooth", "steep": 0.5}
    ref, ref_se = _image_mean(scene, {"type": "path"}, 1024, 32, 60)
    mean, se = _image_mean(scene, settings, 64, 48, 61)
    budget.close(mean, ref, np.hypot(se, ref_se), what="qmc_lighttrace smooth display with steep / path")

    integ, loaded = mi.load_dict(settings), mi.load_dict(scene)
    mi.render(loaded, integrator=integ, spp=1, seed=3)
    paths, solves = integ.paths_used, integ.solve_count
    decided = integ.last_solution._arrays["steep patches 0.5"]
    mi.render(loaded, integrator=integ, spp=1, seed=3)
    assert (integ.paths_used, integ.solve_count) == (paths, solves) == (20000, 1)
    assert integ.last_solution._arrays["steep patches 0.5"] is decided and decided.any()

    def on_itself(self, frame, solution, table):
        return solution_integrator.steep.steep_patches(solution.complete(frame.scene, table), table, self.steep)
    monkeypatch.setattr(solution_integrator.SolutionIntegrator, "steep_patches", on_itself)
    bad, bad_se = _image_mean(scene, settings, 64, 48, 61)
    assert bad - ref > 4 * np.hypot(bad_se, ref_se), (bad, ref, bad_se, ref_se)


@pytest.mark.parametrize("display,refine", [("smooth", False), ("baked", False), ("smooth", True)])
def test_the_displays_show_no_negative_light_beside_the_strip(display, refine, monkeypatch):
    """The field's corrections toward the patch averages take vertices beside the lit strip
    below zero; where the interpolation is negative and the patch's own value is not, the
    display reads the patch's value (``display.SmoothTables``). Measured: no negative
    pixel; the floor's row in front of the strip with ``refine`` 0.0015 +- 0.0001 against
    ``path``'s 0.0014. Test of the test: without that, negative pixels (smooth 431 of 4096
    down to -0.009, baked 663 down to -0.023, refined -0.0036 on that row's mean)."""
    scene = mi.load_dict(panel_on_floor(lift=0.05, resolution=64))
    integrator = mi.load_dict({"type": "qmc_lighttrace", "samples": 100000, "display": display, "refine": refine})

    def lowest():        # (the second render reads the first one's solution through a new view)
        image = np.array(mi.render(scene, integrator=integrator, spp=64, seed=budget.seed(3)))[..., :3]
        return image.min(), int((image.min(axis=-1) < 0).sum())
    low, count = lowest()
    assert low >= 0.0, (low, count)
    without_the_patch_fallback(monkeypatch)
    low, count = lowest()
    assert low < 0.0 and count > 10, (low, count)
