"""The smooth display's steep patches (``steep``, mi_plugins.solution.steep): where the
field fitted to the patch values departs from a patch's own value, the display gathers."""
import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.verify.conformance import runner
from test_darkness import panel_on_floor

pytestmark = pytest.mark.skipif(not mi.variant(), reason="needs a Mitsuba variant")

#: the panel 5 cm above the floor at 64 px: rows 44-47 (central columns) are the shadowed
#: floor just in front of the strip that the light passing under the panel lights
STRIP = np.s_[44:48, 24:40]


def _band(integrator, spp, runs, seed):
    scene = panel_on_floor(lift=0.05, resolution=64)
    images = runner.render_runs(scene, integrator, spp, [budget.seed(seed) * 1000 + r for r in range(runs)])[0]
    means = images[(slice(None),) + STRIP][..., :3].mean(axis=(1, 2, 3))
    return means.mean(), means.std(ddof=1) / np.sqrt(runs)


def test_steep_patches_gather_beside_the_lit_strip():
    """``ray_bundle``'s smooth display with ``steep=0.5`` matches ``path`` on the shadowed
    floor beside the lit strip (+1.1 %, z +0.1 measured); test of the test: without it
    (``steep=0``, the default) the field carries the strip's light into the shadow, +588 %
    (z +52)."""
    ref, ref_se = _band({"type": "path"}, 2048, 8, 50)
    settings = {"type": "ray_bundle", "iterations": 24, "display": "smooth"}
    mean, se = _band(dict(settings, steep=0.5), 16, 8, 55)
    budget.close(mean, ref, np.hypot(se, ref_se), what="ray_bundle smooth display with steep beside the strip / path")
    bad, bad_se = _band(dict(settings, steep=0.0), 16, 8, 55)
    assert bad > 2.0 * ref and bad - ref > 4 * np.hypot(bad_se, ref_se), (bad, ref, bad_se, ref_se)



@pytest.mark.parametrize("integrator", [
    pytest.param({"type": "ray_bundle", "iterations": 24}, id="ray_bundle"),
    pytest.param({"type": "qmc_lighttrace", "samples": 100000}, id="qmc_lighttrace")])
@pytest.mark.xfail(strict=True, reason="known defect: the default smooth display (steep off) carries the lit "
                   "strip's light into the shadowed floor beside it: +588 % (ray_bundle, z +52), +547 % "
                   "(qmc_lighttrace, z +37)")
def test_the_default_smooth_display_beside_the_lit_strip(integrator):
    ref, ref_se = _band({"type": "path"}, 2048, 8, 50)
    mean, se = _band(dict(integrator, display="smooth"), 16, 8, 55)
    budget.close(mean, ref, np.hypot(se, ref_se), what="default smooth display beside the strip / path")
