"""The `halton`, `sobol` and `faure` samplers with Mitsuba's own integrators."""
from unittest import mock

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_plugins import analytic
from mi_plugins.samplers.sequence_sampler import SequenceSampler

import budget

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
    spp = 128 if integrator == "ptracer" else 16
    res = analytic.check(case, {"type": integrator, "max_depth": -1}, spp=spp, runs=16, seed=4,
                         sampler={"type": sampler})
    assert res.passed, res


def _rmse_ratio(sampler, block, runs=8):
    """RMSE of `path` (max_depth 2, 16 spp) on the diffuse sphere with ``sampler``,
    relative to `independent`, over ``runs`` seeds of seed block ``block``."""
    case = analytic.diffuse_sphere(resolution=RES)
    exact = case.expected(2)
    rmse = []
    for name in (sampler, "independent"):
        scene = case.scene({"type": "path", "max_depth": 2}, sampler={"type": name})
        err = [np.mean((np.array(mi.render(scene, spp=16, seed=budget.block_seed(block, j))) - exact) ** 2)
               for j in range(runs)]
        rmse.append(np.sqrt(np.mean(err)))
    return rmse[0] / rmse[1]


for _name in SAMPLERS:
    budget.ratio_statistic("samplers.rmse_ratio_" + _name)(lambda block, _s=_name: _rmse_ratio(_s, block))


# measured RMSE ratios to `independent` at 16 spp (README): sobol 0.43, halton 0.56, faure 0.68
@pytest.mark.parametrize("sampler, bound", [("sobol", 0.6), ("halton", 0.75), ("faure", 0.85)])
def test_lower_rmse_than_independent_on_a_smooth_case(sampler, bound):
    budget.ratio("samplers.rmse_ratio_" + sampler, _rmse_ratio(sampler, 0), hi=bound)


def test_unscrambled_sobol_is_deterministic():
    """Identical unrandomised points in every pixel: every run renders the same image."""
    case = analytic.diffuse_sphere(resolution=RES)
    scene = case.scene({"type": "path", "max_depth": 2}, sampler={"type": "sobol", "scramble": False})
    a, b = (np.array(mi.render(scene, spp=16, seed=budget.seed(s))) for s in (1, 2))
    assert np.array_equal(a, b)


def _neighbour_correlation(sampler, runs=16):
    """Correlation of the errors of horizontally neighbouring pixels (furnace, `path`,
    4 spp, red channel) over ``runs`` renders, and its standard error under independence."""
    case = analytic.furnace(0.5, 0.5, "box", resolution=RES)
    scene = case.scene("path", sampler={"type": sampler})
    e = np.stack([np.array(mi.render(scene, spp=4, seed=budget.seed(40 + r)))[..., 0] - 1.0 for r in range(runs)])
    e -= e.mean()
    pairs = e[:, :, 1:] * e[:, :, :-1]
    return pairs.mean() / np.mean(e * e), 1.0 / np.sqrt(pairs.size)


def _same_scramble_in_every_pixel():
    """Sabotage: every lane believes it is pixel 0 (same scramble/rotation everywhere)."""
    original = SequenceSampler.seed

    def seed(self, seed, wavefront_size=0xFFFFFFFF):
        original(self, seed, wavefront_size)
        self.pixel = dr.zeros(mi.UInt32, dr.width(self.pixel))
    return mock.patch.object(SequenceSampler, "seed", seed)


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_pixels_are_decorrelated(sampler):
    """Each pixel gets its own randomisation: neighbouring pixels' errors are uncorrelated
    (within 4.5 SE of 0). The test of the test: the same scramble in every pixel gives
    strongly correlated neighbours (measured about 0.97 for sobol) and fails."""
    rho, se = _neighbour_correlation(sampler)
    budget.close(rho, 0.0, se, what="%s neighbour error correlation" % sampler)
    with _same_scramble_in_every_pixel():
        rho_bad, _ = _neighbour_correlation(sampler)
    assert rho_bad > 0.5, rho_bad


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_dimensions_beyond_the_tables_fall_back_to_uniform_numbers(sampler):
    """Past the sequence's table (Sobol 1024, Halton/Faure 256 dimensions) the samplers
    draw hashed pseudo-random numbers: uniform (mean 1/2, variance 1/12), independent
    across consecutive dimensions and pixels; and a render that draws ONLY such numbers
    is unbiased (furnace check)."""
    s = mi.load_dict({"type": sampler, "sample_count": 4})
    n = 1 << 16
    s.seed(budget.seed(5), n)
    s.dimension = dr.full(mi.UInt32, type(s).max_dim, n)
    x, y = (np.array(s.next_1d()) for _ in range(2))
    budget.close(x.mean(), 0.5, np.sqrt(1 / 12 / n), what="fallback mean")
    budget.close(np.var(x), 1 / 12, np.sqrt(1 / 180 / n), what="fallback variance")
    budget.close(np.mean((x - 0.5) * (y - 0.5)), 0.0, 1 / 12 / np.sqrt(n), what="consecutive dimensions")
    budget.close(np.mean((x[4:] - 0.5) * (x[:-4] - 0.5)), 0.0, 1 / 12 / np.sqrt(n), what="neighbouring pixels")

    original = SequenceSampler.seed

    def seed_past_the_table(self, seed, wavefront_size=0xFFFFFFFF):
        original(self, seed, wavefront_size)
        self.dimension = dr.full(mi.UInt32, type(self).max_dim, dr.width(self.dimension))
    with mock.patch.object(SequenceSampler, "seed", seed_past_the_table):
        case = analytic.furnace(0.5, 0.5, "box", resolution=RES)
        res = analytic.check(case, "path", spp=16, runs=16, seed=6, sampler={"type": sampler})
    assert res.passed, res


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_same_seed_same_image_other_seed_other_image(sampler):
    scene = analytic.keller_cube(resolution=8).scene("path", sampler={"type": sampler})
    a, b, c = (np.array(mi.render(scene, spp=4, seed=budget.seed(s))) for s in (1, 1, 2))
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_sampler_seed_selects_the_randomisation_with_the_render_seed(sampler):
    """The sampler's `seed` parameter is used: with the same render seed, scenes that
    differ only in it render different images; seed 0 is exactly the image without it;
    the same seeds give the same image (also through fork/clone, which keep the seed)."""
    case = analytic.keller_cube(resolution=8)

    def image(**params):
        scene = case.scene("path", sampler=dict({"type": sampler}, **params))
        return np.array(mi.render(scene, spp=4, seed=budget.seed(1)))

    plain, zero, one, two, one_again = image(), image(seed=0), image(seed=1), image(seed=2), image(seed=1)
    assert np.array_equal(plain, zero)
    assert not np.array_equal(plain, one) and not np.array_equal(one, two)
    assert np.array_equal(one, one_again)
    s = mi.load_dict({"type": sampler, "seed": 7, "sample_count": 8, "scramble": False})
    for copy in (s.fork(), s.clone()):
        assert (copy.sampler_seed, copy.sample_count(), copy.scramble) == (7, 8, False)


def test_sample_count_from_the_scene_and_bad_scramble():
    scene = analytic.keller_cube(resolution=8).scene("path", sampler={"type": "sobol", "sample_count": 8})
    assert scene.sensors()[0].sampler().sample_count() == 8
    with pytest.raises(Exception, match="scramble"):
        analytic.keller_cube(resolution=8).scene("path", sampler={"type": "halton", "scramble": "yes"})
