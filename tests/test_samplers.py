"""The `halton`, `sobol` and `faure` samplers with Mitsuba's own integrators."""
import mitsuba as mi
import numpy as np
import pytest

from mi_plugins import analytic

RES = 16
SAMPLERS = ("halton", "sobol", "faure")


# Every sampler with every integrator on one case, and with `path` on the other cases:
# the full product adds no coverage but triples the (cold-cache) kernel compilation.
COMBINATIONS = ([("bekaert_sierpinski", integrator, sampler) for sampler in SAMPLERS
                 for integrator in ("path", "volpath", "ptracer", "prb")]
                + [(case_name, integrator, sampler) for sampler in SAMPLERS
                   for case_name, integrator in (("diffuse_sphere", "path"),
                                                 ("sierpinski_phong_simulated", "path"),
                                                 ("sierpinski_phong_simulated", "volpath"))])


@pytest.mark.parametrize("case_name, integrator, sampler", COMBINATIONS)
def test_builtin_integrators_with_qmc_samplers_pass(case_name, integrator, sampler):
    case = analytic.cases()[case_name](resolution=RES)
    spp = 64 if integrator == "ptracer" else 16
    res = analytic.check(case, {"type": integrator, "max_depth": -1}, spp=spp, runs=8, seed=4,
                         sampler={"type": sampler})
    assert res.passed, res


# measured RMSE ratios to `independent` at 16 spp (README): sobol 0.43, halton 0.56, faure 0.68
@pytest.mark.parametrize("sampler, bound", [("sobol", 0.6), ("halton", 0.75), ("faure", 0.85)])
def test_lower_rmse_than_independent_on_a_smooth_case(sampler, bound):
    case = analytic.diffuse_sphere(resolution=RES)
    integrator = {"type": "path", "max_depth": 2}
    qmc = analytic.check(case, integrator, spp=16, runs=8, sampler={"type": sampler})
    rnd = analytic.check(case, integrator, spp=16, runs=8, sampler={"type": "independent"})
    assert qmc.passed and rnd.passed
    assert qmc.rmse < bound * rnd.rmse, (qmc.rmse, rnd.rmse)


def test_unscrambled_sobol_is_worse_than_scrambled():
    """The test of the test: identical unrandomised points in every pixel correlate the
    pixels, so the per-pixel averages lose the benefit (and the per-run spread collapses)."""
    case = analytic.diffuse_sphere(resolution=RES)
    integrator = {"type": "path", "max_depth": 2}
    plain = analytic.check(case, integrator, spp=16, runs=4, sampler={"type": "sobol", "scramble": False})
    assert plain.se < 1e-6       # deterministic: every run renders the same image


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_same_seed_same_image_other_seed_other_image(sampler):
    scene = analytic.keller_cube(resolution=8).scene("path", sampler={"type": sampler})
    a, b, c = (np.array(mi.render(scene, spp=4, seed=s)) for s in (1, 1, 2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_sample_count_from_the_scene_and_bad_scramble():
    scene = analytic.keller_cube(resolution=8).scene("path", sampler={"type": "sobol", "sample_count": 8})
    assert scene.sensors()[0].sampler().sample_count() == 8
    with pytest.raises(Exception, match="scramble"):
        analytic.keller_cube(resolution=8).scene("path", sampler={"type": "halton", "scramble": "yes"})
