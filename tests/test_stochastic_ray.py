"""Tests of the `stochastic_ray` integrator (stochastic iteration, single-ray operator).

Budgets: a render runs ``spp * width * height`` chains in lockstep, and the cost of a
step grows far less than linearly with the number of chains (per-iteration overhead),
so the checks use many chains (spp 16-256), few averaged steps and 16 runs: every
passing check detects a relative error of the mean below 2 % (measured 0.3-1.5 % over
seed offsets 0-2) and, where the exact image varies, a contrast error below 0.1. The
estimator has light tails (480 runs of three cases: no run beyond 3.9 SD), so the
Student-t checks hold their level.
"""
import functools

import numpy as np
import pytest

import mitsuba as mi
from mi_plugins.verify import analytic
from mi_plugins.base import errors
from mi_plugins.verify.analytic import harness, stats

import budget
from conftest import furnace_rmse, scalar_variant_refusal

RES = 16
#: the default chain set-up of the checks: 8 steps of burn-in, 8 averaged steps
BASE = {"iterations": 16, "burn_in": 8}

# (case name, integrator overrides, spp, resolution). High-albedo cases need a longer
# burn-in: the power defect of the paper's eq. 20 (measured below: relative defect
# a^(B+2) (1 - a^M) / (M (1 - a)) after B burn-in and M averaged steps) must stay far
# below the statistical error. Measured at 65536 chains (tolerance ~0.6 %): the
# lightsource Sierpinski case (directional emitters, albedo close to 1 in places)
# is 2 % low with burn-in 32 and within 0.1 % with 64; the others are unbiased with 16-24.
CASES = [
    ("furnace_box", BASE, 32, RES),
    ("furnace_sphere_mesh", BASE, 32, RES),
    ("furnace_sierpinski", BASE, 64, RES),
    ("bekaert_box", BASE, 32, RES),
    ("bekaert_sierpinski", {"iterations": 32, "burn_in": 24}, 32, RES),
    ("diffuse_sphere", BASE, 32, RES),
    ("mirror_sphere", BASE, 16, RES),
    ("constant_brdf_diffuse_sphere", {"iterations": 48, "burn_in": 32}, 256, 8),
    ("constant_brdf_phong_box", {"iterations": 24, "burn_in": 16}, 64, RES),
    ("sierpinski_phong_simulated", {"iterations": 24, "burn_in": 16}, 128, RES),
    ("constant_lightsource_box", {"iterations": 32, "burn_in": 24}, 128, RES),
    ("constant_lightsource_sierpinski", {"iterations": 72, "burn_in": 64}, 64, RES),
]

#: a furnace of albedo 0.95: a long burn-in (the max_iterations tests)
BRIGHT_FURNACE = analytic.furnace(0.95, 0.05, "box", resolution=4)


def integrator(**kw):
    return dict({"type": "stochastic_ray"}, **kw)


def render_runs(scene, spp, seed, runs=16):
    """``runs`` independent renders (numpy, runs x H x W x 3) with the suite's seed offset."""
    return harness.render_runs(scene, spp, runs, seed)


def close_t(value, target, se, runs, slack=0.0, what="value"):
    """budget.close for a mean whose SE was estimated from ``runs`` runs: the Student-t
    bound at the suite's level (the recorded false-failure probability stays exact)."""
    scale = stats.t_quantile_for_z(budget.Z, runs - 1) / budget.Z
    budget.close(value, target, se * scale, slack=slack, what=what)


@pytest.mark.parametrize("name,extra,spp,res", CASES, ids=[c[0] for c in CASES])
def test_analytic_cases(name, extra, spp, res):
    case = analytic.cases()[name](resolution=res)
    res = analytic.check(case, integrator(**extra), spp=spp, runs=16, seed=3, bias=case.known_bias)
    assert res.passed, res


@functools.lru_cache(maxsize=None)
def truncated_renders(depth):
    """(furnace box case, 16 renders with max_depth ``depth``), computed once per session."""
    case = analytic.furnace(0.5, 0.5, "box", resolution=RES)
    images = render_runs(case.scene(integrator(max_depth=depth, **BASE)), 32, seed=1)
    images.setflags(write=False)
    return case, images


@pytest.mark.parametrize("depth", [1, 2, 3])
def test_truncated_depths(depth):
    case, images = truncated_renders(depth)
    res = harness.compare(images, case.expected(depth))
    assert res["passed"], res["failures"]


def test_truncated_depth_against_untruncated_value_fails():
    """Test of the test: depth-3 renders pass against the depth-3 value (7/8 of the
    furnace's) and fail against the unbounded value by the 12.5 % the truncation takes."""
    case, images = truncated_renders(3)
    ok = harness.compare(images, case.expected(3))
    assert ok["passed"], ok["failures"]
    bad = harness.compare(images, case.expected(-1))
    assert not bad["passed"] and bad["z"] < -20, (bad["z"], bad["failures"])
    close_t(1.0 - bad["mean"] / bad["expected_mean"], 0.125, bad["se"], bad["runs"], what="relative deficit")


def test_short_chains_without_burn_in_show_the_power_defect():
    """The paper's power defect (eq. 20) of few steps without burn-in on a bright furnace
    (albedo a = 0.8, Le = 0.2, L = 1): the chains start from the emitters, so step n
    estimates the light of up to n + 1 bounces, and M averaged steps miss the relative
    a^2 (1 - a^M) / (M (1 - a)) = 1/3 of L (M = 8). Measured: 0.332 +- 0.001. The renders
    match the defective value and fail the exact one."""
    a, le, steps = 0.8, 0.2, 8
    case = analytic.furnace(a, le, "box", resolution=RES)
    images = render_runs(case.scene(integrator(iterations=steps, burn_in=0)), 32, seed=1)
    defect = a * a * (1 - a ** steps) / (steps * (1 - a))
    ok = harness.compare(images, case.expected(-1) * (1.0 - defect))
    assert ok["passed"], ok["failures"]
    bad = harness.compare(images, case.expected(-1))
    assert not bad["passed"] and bad["z"] < -20, (bad["z"], bad["failures"])


def test_a_burn_in_beyond_max_iterations_is_refused_not_averaged():
    """A furnace of albedo 0.95 needs a burn-in of about 250 steps for a power defect below
    1e-3 (lambda^b / (1 - lambda)^2): with max_iterations=64 the render is refused, naming the
    steps needed, instead of returning an image about 10 % too dark. Its counterpart is the
    next test: at the default limit the same furnace renders and matches."""
    with pytest.raises(errors.NotConverged, match=r"^stochastic_ray: not converged within max_iterations=64: the "
                                                   r"scene's effective albedo is 0\.9\d*: a burn-in of (\d+) steps"):
        mi.render(BRIGHT_FURNACE.scene(integrator(iterations=8, max_iterations=64)), spp=1, seed=budget.seed(3))


def test_the_bright_furnace_renders_at_the_default_max_iterations():
    """The furnace the test above refuses renders at the default limit (4096) and matches its
    exact radiance."""
    means = [float(np.mean(mi.render(BRIGHT_FURNACE.scene(integrator(iterations=8)), spp=4, seed=budget.seed(3 + k))))
             for k in range(8)]
    se = float(np.std(means, ddof=1) / np.sqrt(len(means)))
    budget.close(np.mean(means), 1.0, se, slack=0.002, what="albedo-0.95 furnace at the default max_iterations")


def test_hide_emitters():
    """hide_emitters as Mitsuba means it: camera rays pass through area emitters. In the
    furnace box every wall emits, so the camera sees nothing (black, as Mitsuba's path
    renders it); without hide_emitters the same renders show L = 1. (What lies behind a
    hidden lamp is checked against path by the coverage row case:hide_emitters.)"""
    case = analytic.furnace(0.5, 0.5, "box", resolution=RES)
    hidden = render_runs(case.scene(integrator(hide_emitters=True, **BASE)), 4, seed=5)
    assert np.all(hidden == 0)
    path = np.array(mi.render(case.scene({"type": "path", "hide_emitters": True}), spp=16))
    assert np.all(path == 0)
    shown = render_runs(case.scene(integrator(**BASE)), 4, seed=5)
    assert shown.mean() > 0.9


def wrong_images(exact):
    """The exact image mirrored left-right, and with its contrast 25 % too high (same mean)."""
    mean = exact.mean()
    return {"mirrored": exact[:, ::-1], "contrast": mean + 1.25 * (exact - mean)}


def assert_structure_failures(images, exact, **kw):
    """The renders pass against ``exact`` and fail the structure test against the wrong
    images, by the slope the exact image predicts (|z| > 8)."""
    ok = harness.compare(images, exact, **kw)
    assert ok["passed"], ok["failures"]
    structure = exact - exact.mean()
    for name, wrong in wrong_images(exact).items():
        out = harness.compare(images, wrong, **kw)
        assert not out["passed"] and any("image structure" in f for f in out["failures"]), (name, out["failures"])
        wrong_structure = wrong - wrong.mean()
        # the slope a correct render has on the wrong image's structure
        predicted = float(np.sum(structure * wrong_structure) / np.sum(wrong_structure ** 2))
        assert abs(predicted - 1.0) > 0.15, (name, predicted)
        assert abs(out["slope"] - 1.0) > 8 * out["slope_se"], (name, out["slope"], out["slope_se"])
        close_t(out["slope"], predicted, out["slope_se"], out["runs"], slack=out["slope_tolerance"]
                - stats.t_quantile_for_z(budget.Z, out["runs"] - 1) * out["slope_se"], what=name + " slope")


def test_wrong_images_fail():
    """Test of the test on the (analytic) diffuse sphere: the renders pass against the
    exact image and fail the structure test against the mirrored image and an image
    with a 25 % too high contrast (both have the right mean)."""
    case = analytic.diffuse_sphere(0.5, resolution=RES)
    images = render_runs(case.scene(integrator(**BASE)), 64, seed=7)
    assert_structure_failures(images, case.expected(-1))


# ------------------------------------------------------------------ ratio statistics
def _rmse(averaged, block, first_seed):
    seeds = [budget.block_seed(block, first_seed + j) for j in range(6)]
    return furnace_rmse(integrator(iterations=averaged + 8, burn_in=8), seeds, RES)


@budget.ratio_statistic("stochastic_ray.rmse_ratio_iterations")
def rmse_ratio_iterations(block):
    """Per-pixel RMSE (furnace box, 256 chains, 6 seeds each) with 8 averaged steps over
    the RMSE with 32: 1/sqrt(steps) predicts 2."""
    return _rmse(8, block, 0) / _rmse(32, block, 100)


def test_error_shrinks_like_inverse_sqrt_of_iterations():
    # measured over 24 seed blocks: 1.93 .. 2.10 (median 2.00, log-SD 0.025); a ratio of 1 (steps not
    # averaged) or 4 (1/steps) is far outside
    budget.ratio("stochastic_ray.rmse_ratio_iterations", rmse_ratio_iterations(0), 1.65, 2.45)


@budget.ratio_statistic("stochastic_ray.rmse_ratio_spp")
def rmse_ratio_spp(block):
    """Per-pixel RMSE (furnace box, 4 seeds each) at spp 1 over the RMSE at spp 4: spp
    scales the number of chains, so 1/sqrt(chains) predicts 2."""
    case = analytic.furnace(0.5, 0.5, "box", resolution=RES)
    scene = case.scene(integrator(**BASE))
    exact = case.expected()

    def rmse(spp, first):
        errs = [np.mean((np.array(mi.render(scene, spp=spp, seed=budget.block_seed(block, first + j))) - exact) ** 2)
                for j in range(4)]
        return float(np.sqrt(np.mean(errs)))
    return rmse(1, 0) / rmse(4, 100)


def test_spp_scales_the_number_of_chains():
    # measured over 24 seed blocks: 1.92 .. 2.15 (median 2.03, log-SD 0.031); spp that did not add chains
    # would give 1
    budget.ratio("stochastic_ray.rmse_ratio_spp", rmse_ratio_spp(0), 1.6, 2.5)


# ------------------------------------------------------------------ behaviour
def test_fixed_seed_is_deterministic():
    scene = analytic.furnace(0.5, 0.5, "box", resolution=RES).scene(integrator(iterations=4, burn_in=1))
    s = budget.seed(5)
    a, b = np.array(mi.render(scene, seed=s, spp=1)), np.array(mi.render(scene, seed=s, spp=1))
    c = np.array(mi.render(scene, seed=s + 1, spp=1))
    # the same image up to the order of float additions in parallel sums (measured: at most
    # 2.4e-7 on values near 1); another seed differs by the noise (about 0.1)
    assert np.allclose(a, b, rtol=1e-5, atol=1e-6), float(np.abs(a - b).max())
    assert np.abs(a - c).max() > 1e-3


def test_progress_callback_and_early_stop():
    scene = analytic.furnace(0.5, 0.5, "box", resolution=RES).scene(integrator(iterations=10, burn_in=1))
    integ = scene.integrator()
    calls = []

    def callback(done, total):
        calls.append((done, total))
        return done < 4
    integ.progress_callback = callback
    img = np.array(mi.render(scene, spp=1, seed=budget.seed(0)))
    integ.progress_callback = None
    assert calls == [(1, 10), (2, 10), (3, 10), (4, 10)]
    assert integ.progress.done == 4
    assert np.all(np.isfinite(img)) and 0.5 < img.mean() < 1.5


def test_xml_and_int_sensor():
    scene_dict = analytic.furnace(0.5, 0.5, "box", resolution=8).scene_dict(integrator(iterations=4, burn_in=1))
    scene = mi.load_dict(scene_dict)
    img = np.array(scene.integrator().render(scene, 0, seed=budget.seed(1), spp=1))
    assert img.shape == (8, 8, 3)
    xml = mi.load_string("""<scene version="3.0.0"><integrator type="stochastic_ray">
        <integer name="iterations" value="5"/><integer name="burn_in" value="2"/>
        <boolean name="hide_emitters" value="true"/></integrator></scene>""")
    assert xml.integrator().iterations == 5 and xml.integrator().burn_in == 2 and xml.integrator().hide_emitters


@pytest.mark.parametrize("params,needle", [
    ({"iterations": 0}, "iterations=0"),
    ({"iterations": -3}, "iterations=-3"),
    ({"iterations": 4, "burn_in": 4}, "burn_in=4"),
    ({"burn_in": -1}, "burn_in=-1"),
    ({"max_depth": -2}, "max_depth=-2"),
])
def test_bad_parameters(params, needle):
    with pytest.raises(Exception) as err:
        mi.load_dict(integrator(**params))
    assert needle in str(err.value) and "range" in str(err.value)


def test_wrong_variant():
    """A scalar variant is refused with a message naming it and the supported variants
    (by mi_plugins.register(), or by the integrator's constructor if registered anyway)."""
    refused, out = scalar_variant_refusal("stochastic_ray")
    assert refused and "scalar_rgb" in out and "llvm_ad_rgb" in out, out


def test_textured_area_light_on_a_mesh_carries_its_power():
    """An ``area`` light with a bitmap radiance on an obj sphere (its uv map has seams):
    Mitsuba 3.9.1's own ray and direction sampling of it lose power (docs/findings.md),
    the package's light rays sample the shape uniformly. Direct light (max_depth 2) on
    an open floor against Mitsuba's ``direct`` with BSDF sampling only, which never
    samples the emitter. Test of the test: the emitter-sampled ``direct`` is 9 % low."""
    from mi_plugins.verify.coverage import files, rows
    sphere = files.obj_file(rows._icosphere(), "coverage_sphere")
    scene = mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 40, "to_world": mi.ScalarTransform4f().look_at([0, 6, 12], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8, "pixel_format": "rgb"}},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(20),
                  "bsdf": {"type": "diffuse", "reflectance": 0.8}},
        "light": {"type": "obj", "filename": sphere, "to_world": mi.ScalarTransform4f().translate([0, 2, 0]),
                  "emitter": {"type": "area", "radiance": rows.bitmap(rows.noise((8, 8, 3), 12, 0.3, 1.0))}}})

    def means(integ, spp, seeds):
        return np.array([np.array(mi.render(scene, integrator=mi.load_dict(integ), spp=spp, seed=s)).mean()
                         for s in seeds])
    reference = means({"type": "direct", "emitter_samples": 0, "bsdf_samples": 16}, 64, range(8))
    ours = means(integrator(max_depth=2, iterations=16, burn_in=4), 64, range(100, 108))
    emitter_sampled = means({"type": "direct", "emitter_samples": 16, "bsdf_samples": 0}, 64, range(8))
    se = lambda a: a.std(ddof=1) / np.sqrt(len(a))
    z = (ours.mean() - reference.mean()) / np.hypot(se(ours), se(reference))
    assert abs(z) < 4, (ours.mean(), reference.mean(), z)
    z_wrong = (emitter_sampled.mean() - reference.mean()) / np.hypot(se(emitter_sampled), se(reference))
    assert z_wrong < -4, (emitter_sampled.mean(), reference.mean(), z_wrong)
