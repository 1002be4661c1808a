"""Tests of the `stochastic_ray` integrator (stochastic iteration, single-ray operator)."""
import numpy as np
import pytest

import mitsuba as mi
import mi_plugins
from mi_plugins import analytic

from conftest import furnace_rmse, scalar_variant_refusal

RES = 16

# (case name, integrator overrides): high-albedo cases (constant-radiance BRDF/lightsource,
# albedo close to 1) need a longer burn-in so that the power defect of the paper's eq. 20,
# ~ lambda^burn_in / (1 - lambda)^2, stays far below the statistical error.
CASES = [
    ("furnace_box", {}),
    ("furnace_sphere_mesh", {}),
    ("furnace_sierpinski", {}),
    ("bekaert_box", {}),
    ("bekaert_sierpinski", {"iterations": 64, "burn_in": 32}),
    ("diffuse_sphere", {}),
    ("mirror_sphere", {}),
    ("constant_brdf_diffuse_sphere", {"iterations": 96, "burn_in": 64}),
    ("constant_brdf_phong_box", {"iterations": 96, "burn_in": 64}),
    ("sierpinski_phong_simulated", {"iterations": 96, "burn_in": 64}),
    ("constant_lightsource_box", {"iterations": 96, "burn_in": 64}),
    ("constant_lightsource_sierpinski", {"iterations": 96, "burn_in": 64}),
]


def integrator(**kw):
    return dict({"type": "stochastic_ray"}, **kw)


@pytest.mark.parametrize("name,extra", CASES, ids=[c[0] for c in CASES])
def test_analytic_cases(name, extra):
    case = analytic.cases()[name](resolution=RES)
    res = analytic.check(case, integrator(**extra), spp=1, runs=8, seed=3, bias=case.known_bias)
    assert res.passed, res


@pytest.mark.parametrize("depth", [1, 2, 3])
def test_truncated_depths(depth):
    case = analytic.furnace(0.5, 0.5, "box", resolution=RES)
    res = analytic.check(case, integrator(max_depth=depth), spp=1, runs=8, seed=1)
    assert res.passed, res


def test_truncated_depth_against_untruncated_value_fails():
    """Test of the test: a depth-3 render compared with the unbounded value must fail."""
    case = analytic.furnace(0.5, 0.5, "box", resolution=RES)
    res = analytic.check(case, integrator(max_depth=3), spp=1, runs=8, seed=1, max_depth=-1)
    assert not res.passed, res


def test_short_chains_without_burn_in_show_the_power_defect():
    """Test of the test: the paper's power defect (eq. 20) of few steps without burn-in
    on a bright furnace (albedo 0.8: defect ~ 1/M * lambda^2/(1-lambda)^2 * Le) is caught."""
    case = analytic.furnace(0.8, 0.2, "box", resolution=RES)
    res = analytic.check(case, integrator(iterations=8, burn_in=0), spp=2, runs=8, seed=1)
    assert not res.passed and res.mean < res.expected_mean, res


def _rmse(iterations, seeds):
    return furnace_rmse(integrator(iterations=iterations + 8, burn_in=8), seeds, RES)


def test_error_shrinks_like_inverse_sqrt_of_iterations():
    small, large = _rmse(8, range(6)), _rmse(32, range(100, 106))
    ratio = small / large          # 4x the averaged steps: expected ratio 2
    assert 1.5 < ratio < 2.7, (small, large, ratio)


def test_fixed_seed_is_deterministic():
    scene = analytic.furnace(0.5, 0.5, "box", resolution=RES).scene(integrator(iterations=4, burn_in=1))
    a, b = np.array(mi.render(scene, seed=5, spp=1)), np.array(mi.render(scene, seed=5, spp=1))
    c = np.array(mi.render(scene, seed=6, spp=1))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_spp_scales_the_number_of_chains():
    scene = analytic.furnace(0.5, 0.5, "box", resolution=RES).scene(integrator(iterations=4, burn_in=1))
    exact = 1.0
    e1 = np.std([np.mean(np.array(mi.render(scene, spp=1, seed=s))) - exact for s in range(6)])
    e4 = np.std([np.mean(np.array(mi.render(scene, spp=4, seed=s))) - exact for s in range(6)])
    assert e4 < e1


def test_progress_callback_and_early_stop():
    scene = analytic.furnace(0.5, 0.5, "box", resolution=RES).scene(integrator(iterations=10, burn_in=1))
    integ = scene.integrator()
    calls = []

    def callback(done, total):
        calls.append((done, total))
        return done < 4
    integ.progress_callback = callback
    img = np.array(mi.render(scene, spp=1, seed=0))
    integ.progress_callback = None
    assert calls == [(1, 10), (2, 10), (3, 10), (4, 10)]
    assert integ.iterations_done == 4
    assert np.all(np.isfinite(img)) and 0.5 < img.mean() < 1.5


def test_xml_and_int_sensor():
    scene_dict = analytic.furnace(0.5, 0.5, "box", resolution=8).scene_dict(integrator(iterations=4, burn_in=1))
    scene = mi.load_dict(scene_dict)
    img = np.array(scene.integrator().render(scene, 0, seed=1, spp=1))
    assert img.shape == (8, 8, 3)
    xml = mi.load_string("""<scene version="3.0.0"><integrator type="stochastic_ray">
        <integer name="iterations" value="5"/><integer name="burn_in" value="2"/></integrator></scene>""")
    assert xml.integrator().iterations == 5 and xml.integrator().burn_in == 2


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
