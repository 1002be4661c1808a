"""The `halton`, `sobol` and `faure` samplers with Mitsuba's own integrators."""
from unittest import mock

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_plugins.verify import analytic
from mi_plugins.base import sequences
from mi_plugins.samplers.sequence_sampler import SequenceSampler

import budget
from test_padded_samplers import PADDED

RES = 16
SAMPLERS = ("halton", "sobol", "faure")


# Every sampler with every integrator on one case, and with `path` on the other cases:
# the full product adds no coverage but triples the (cold-cache) kernel compilation. The
# padded samplers run with `path` in tests/test_padded_samplers.py and the verify matrix;
# here with the other three (`ptracer`'s wavefront is not one lane per pixel sample).
COMBINATIONS = ([("bekaert_sierpinski", integrator, sampler) for sampler in SAMPLERS
                 for integrator in ("path", "volpath", "ptracer", "prb")]
                + [("bekaert_sierpinski", integrator, sampler) for sampler in PADDED
                   for integrator in ("volpath", "ptracer", "prb")]
                + [(case_name, integrator, sampler) for sampler in SAMPLERS
                   for case_name, integrator in (("diffuse_sphere", "path"),
                                                 ("sierpinski_phong_simulated", "path"),
                                                 ("sierpinski_phong_simulated", "volpath"))])


@pytest.mark.parametrize("case_name, integrator, sampler", COMBINATIONS)
def test_builtin_integrators_with_qmc_samplers_pass(case_name, integrator, sampler):
    case = analytic.cases()[case_name](resolution=RES)
    spp = 128 if integrator == "ptracer" else 16
    res = analytic.check(case, {"type": integrator, "max_depth": -1}, spp=spp, runs=16, seed=budget.seed(4),
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


# measured RMSE ratios to `independent` at 16 spp (README): sobol 0.43, halton 0.57, faure 0.67
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


# ---------------------------------------------------------------------- Mitsuba's multi-pass protocol
def _passes(sampler, n, k, pixels, scramble, draws=2, seed=7, past_table=False):
    """Values (pixels, n, draws) that a sampler with sample_count n gives every pixel over
    the n / k passes of Mitsuba's protocol (set_samples_per_wavefront(k), seed(seed,
    pixels * k), advance() between passes): [pixel, sample index, number]. With
    ``past_table`` the last draw is the first dimension beyond the sequence's table."""
    s = mi.load_dict({"type": sampler, "sample_count": n, "scramble": scramble})
    s.set_samples_per_wavefront(k)
    s.seed(budget.seed(seed), pixels * k)
    out = np.full((pixels, n, draws), np.nan)
    lane = np.arange(pixels * k)
    for p in range(n // k):
        if p:
            s.advance()
        values = [np.array(s.next_1d()) for _ in range(draws - 1)]
        if past_table:
            s.dimension = dr.full(mi.UInt32, type(s).max_dim, pixels * k)
        values.append(np.array(s.next_1d()))
        out[lane // k, p * k + lane % k] = np.stack(values, axis=1)
    return out


@pytest.mark.parametrize("sampler", SAMPLERS)
@pytest.mark.parametrize("k", [1, 2, 8])
def test_passes_give_every_pixel_the_sample_indices_0_to_n_minus_1(sampler, k):
    """Unscrambled: pass p's lane j holds point p * k + j % k of the sequence, so over the
    passes every pixel gets exactly the points 0 .. N-1 (dimensions 0 and 1 after every
    advance(), which resets the dimension)."""
    got = _passes(sampler, 8, k, pixels=5, scramble=False)
    assert np.array_equal(got, np.broadcast_to(sequences.points(sampler, 8, 2).astype(np.float32), got.shape))


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_scrambled_passes_give_the_points_of_one_pass(sampler):
    """Scrambled: the union of 4 passes of 2 samples per pixel is, per pixel and sample
    index, exactly the single-pass render's samples (in the table and past it); the single
    pass (k = N) is lane j = sample j % N of pixel j // N, scrambled with the seed
    hash32(pixel, base seed) as qmc defines the scramble."""
    one = _passes(sampler, 8, 8, pixels=6, scramble=True, draws=3)
    assert np.array_equal(_passes(sampler, 8, 2, pixels=6, scramble=True, draws=3), one)
    assert np.array_equal(_passes(sampler, 8, 2, pixels=6, scramble=True, past_table=True),
                          _passes(sampler, 8, 8, pixels=6, scramble=True, past_table=True))
    s = mi.load_dict({"type": sampler, "sample_count": 8})
    s.seed(budget.seed(7), 6 * 8)           # no set_samples_per_wavefront: one pass of sample_count
    lane = dr.arange(mi.UInt32, 6 * 8)
    x = sequences.sample(sampler, lane % 8, 1, scramble=True, seed=sequences.hash32(lane // 8, s.base_seed))
    assert np.array_equal(np.array(x), one[:, :, 1].ravel())
    s.next_1d()
    assert np.array_equal(np.array(s.next_1d()), one[:, :, 1].ravel())


def test_set_samples_per_wavefront_checks_and_applies_to_the_next_seed_only():
    """It must divide sample_count (Mitsuba's check); fork and clone keep the state; it
    applies to the next seed() only (Mitsuba's C++ renderer sets its own value through a
    non-virtual call a Python sampler cannot see)."""
    s = mi.load_dict({"type": "sobol", "sample_count": 8, "scramble": False})
    with pytest.raises(Exception, match="multiple"):
        s.set_samples_per_wavefront(3)
    s.set_samples_per_wavefront(2)
    assert s.fork().next_per_pixel == 2
    s.seed(1, 6)
    s.advance()
    s.next_1d()
    c = s.clone()
    assert np.array_equal(np.array(c.next_2d()), np.array(s.next_2d()))     # points 2, 3 of pixels 0 .. 2
    assert np.array_equal(np.array(s.sample_index), [2, 3] * 3)
    s.seed(1, 6)                             # without set_samples_per_wavefront: one pass of 8
    assert np.array_equal(np.array(s.sample_index), range(6))


def test_mitsuba_independent_sampler_continues_its_streams_across_passes():
    """Mitsuba's own `independent` sampler under the same protocol: advance() just
    continues each lane's stream (so the passes draw new, independent numbers), which is
    what callers of the protocol need from any sampler."""
    def draws(advance):
        s = mi.load_dict({"type": "independent", "sample_count": 8})
        s.set_samples_per_wavefront(2)
        s.seed(budget.seed(8), 32)
        first = [np.array(s.next_1d()) for _ in range(3)]
        if advance:
            s.advance()
        return first, [np.array(s.next_1d()) for _ in range(3)]
    (a0, a1), (b0, b1) = draws(True), draws(False)
    assert np.array_equal(a0, b0) and np.array_equal(a1, b1)
    assert not np.array_equal(np.stack(a0), np.stack(a1))
