"""Keller's `qmc_lighttrace` against the analytic cases."""
import mitsuba as mi
import numpy as np
import pytest

from mi_plugins import analytic, qmc
from mi_plugins.meshtable import NonMeshShapeError

RES = 16


def lighttrace(**kw):
    d = {"type": "qmc_lighttrace", "samples": 20000, "max_depth": 6}
    d.update(kw)
    return d


@pytest.mark.parametrize("sequence", ["sobol", "halton", "faure", "lcg", "independent"])
def test_keller_cube_exact_truncated_value(sequence):
    """M = 6: the image holds paths of up to M + 3 = 9 segments (Mitsuba max_depth 9)."""
    case = analytic.keller_cube(resolution=RES)
    res = analytic.check(case, lighttrace(sequence=sequence), spp=4, runs=6, max_depth=9)
    assert res.passed, res


@pytest.mark.parametrize("case_name", ["furnace_sierpinski", "bekaert_sierpinski", "diffuse_sphere_mesh",
                                       "sierpinski_diffuse_simulated"])
def test_cases_with_large_m(case_name):
    case = analytic.cases()[case_name](resolution=RES)
    # M = 29: truncation below 0.7^32 / 0.3 < 1e-4, stated as explicit bias (plus the case's own)
    res = analytic.check(case, lighttrace(max_depth=29), spp=4, runs=6, max_depth=-1,
                         bias=1e-4 + case.known_bias)
    assert res.passed, res


def test_truncation_is_visible_when_checked_against_the_untruncated_value():
    case = analytic.furnace(albedo=0.7, emission=0.3, geometry="box", resolution=RES)
    res = analytic.check(case, lighttrace(max_depth=1), spp=4, runs=6, max_depth=-1)
    assert not res.passed and res.mean < res.expected_mean     # the report: truncation underestimates
    ok = analytic.check(case, lighttrace(max_depth=1), spp=4, runs=6, max_depth=4)
    assert ok.passed, ok


def test_per_triangle_radiance_of_the_cube():
    scene = analytic.keller_cube(resolution=8).scene(lighttrace(samples=100000, max_depth=29))
    integrator = scene.integrator()
    radiance, areas = integrator.preprocess(scene, seed=0)
    assert radiance.shape == (12, 3) and np.isclose(areas.sum(), 24.0)
    delta_a = np.sqrt(np.mean((radiance[:, 0] - 0.5) ** 2))
    assert delta_a < 2e-3 and integrator.paths_used == 100000


def test_adaptive_termination_stops_earlier_for_larger_epsilon():
    case = analytic.keller_cube(resolution=8)
    used = {}
    for eps in (1e-2, 1e-4):
        scene = case.scene(lighttrace(epsilon=eps, batch=1000, patience=2, max_samples=200000))
        integrator = scene.integrator()
        integrator.preprocess(scene)
        used[eps] = integrator.paths_used
        assert len(integrator.delta_e_history) >= 2
    assert used[1e-2] < used[1e-4] <= 200000


def test_neighbour_sharing_passes():
    case = analytic.bekaert("box", resolution=RES)
    plain = analytic.check(case, lighttrace(max_depth=29, gather_samples=4), spp=4, runs=6, max_depth=-1,
                           bias=1e-4)
    shared = analytic.check(case, lighttrace(max_depth=29, gather_samples=4, share_neighbors=True), spp=4,
                            runs=6, max_depth=-1, bias=1e-4)
    assert plain.passed and shared.passed, (plain, shared)


def test_same_seed_same_image():
    scene = analytic.keller_cube(resolution=8).scene(lighttrace(samples=5000))
    a, b, c = (np.array(mi.render(scene, spp=2, seed=s)) for s in (3, 3, 4))
    # identical up to the order of parallel floating-point additions in the deposit step
    assert np.allclose(a, b, rtol=1e-5, atol=1e-6) and not np.allclose(a, c, rtol=1e-3)


@pytest.mark.parametrize("params, error, message", [
    ({"epsilon": 0.0}, ValueError, "epsilon=0.0 must be > 0"),
    ({"samples": 0}, ValueError, "samples=0 must be an integer >= 1"),
    ({"sequence": "niederreiter"}, ValueError, "sequence='niederreiter'"),
    ({"sequence": "halton", "max_depth": 200}, qmc.DimensionError, "needs 404 dimensions"),
])
def test_bad_parameters(params, error, message):
    with pytest.raises(Exception, match=message):
        mi.load_dict(lighttrace(**params))


def test_non_mesh_shapes_are_refused():
    case = analytic.furnace(geometry="sphere", resolution=8)
    with pytest.raises(Exception) as info:
        mi.render(case.scene(lighttrace()), spp=1)
    text = str(info.value) + str(info.value.__cause__ or "")
    assert "is not a triangle mesh" in text and "sphere_mesh" in text
