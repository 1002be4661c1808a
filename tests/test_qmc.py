"""Sequences of mi_plugins.base.sequences against independent implementations (scipy, libc)."""
import ctypes

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import scipy.stats.qmc as sq

from mi_plugins.base import sequences

import budget


def test_halton_matches_scipy():
    assert np.abs(sequences.points("halton", 4096, 32) - sq.Halton(32, scramble=False).random(4096)).max() < 1e-6


@pytest.mark.parametrize("dims, n", [(64, 4096), (1024, 16)])
def test_sobol_matches_scipy_in_gray_code_order(dims, n):
    i = np.arange(n)
    gray = mi.UInt32(i ^ (i >> 1))            # scipy enumerates Sobol points in Gray-code order
    ours = np.stack([np.array(sequences.sobol(gray, d)) for d in range(dims)], axis=1)
    assert np.abs(ours - sq.Sobol(dims, scramble=False).random(n)).max() == 0.0


@pytest.mark.parametrize("dims, n", [(64, 4096), (1024, 16)])
def test_jit_dimension_sobol_matches_scipy(dims, n):
    """sobol with the dimension a per-lane JIT value (what the samplers use) against
    scipy, all dimensions in one kernel."""
    i = np.arange(n)
    gray = np.repeat(i ^ (i >> 1), dims).astype(np.uint32)
    dim = np.tile(np.arange(dims), n).astype(np.uint32)
    ours = np.array(sequences.sobol(mi.UInt32(gray), mi.UInt32(dim))).reshape(n, dims)
    assert np.abs(ours - sq.Sobol(dims, scramble=False).random(n)).max() == 0.0


def test_jit_dimension_halton_matches_scipy_and_faure_is_its_permutation():
    n, dims = 1024, 48
    index = np.repeat(np.arange(n), dims).astype(np.uint32)
    dim = np.tile(np.arange(dims), n).astype(np.uint32)
    ours = np.array(sequences.halton(mi.UInt32(index), mi.UInt32(dim))).reshape(n, dims)
    assert np.abs(ours - sq.Halton(dims, scramble=False).random(n)).max() < 1e-6
    faure = np.array(sequences.faure(mi.UInt32(index), mi.UInt32(dim))).reshape(n, dims)
    assert np.abs(faure - sequences.points("faure", n, dims)).max() < 1e-6
    assert np.abs(faure[:, 0] - ours[:, 0]).max() < 1e-7          # base 2: Faure's permutation is the identity


def test_lcg_is_drand48():
    libc = ctypes.CDLL("libc.so.6")
    libc.drand48.restype = ctypes.c_double
    libc.srand48(12345)
    reference = np.array([libc.drand48() for _ in range(3 * 50)]).reshape(50, 3)
    assert np.abs(sequences.points("lcg", 50, 3, seed=12345) - reference).max() < 1e-7


def test_faure_permutations_of_the_report():
    assert list(sequences.faure_permutation(5)) == [0, 3, 2, 1, 4]
    assert list(sequences.faure_permutation(7)) == [0, 2, 5, 3, 1, 4, 6]
    for b in (2, 3, 11, 29, 97):
        assert sorted(sequences.faure_permutation(b)) == list(range(b))


def test_faure_is_permuted_halton():
    idx = mi.UInt32(np.arange(25))
    x = np.array(sequences.faure(idx, 2))  # base 5, digit permutation (0 3 2 1 4)
    i = np.arange(25)
    perm = np.array([0, 3, 2, 1, 4])
    assert np.allclose(x, perm[i % 5] / 5 + perm[(i // 5) % 5] / 25, atol=1e-7)


def test_hammersley_first_coordinate_and_rest():
    p = sequences.points("hammersley", 8, 3)
    assert np.allclose(p[:, 0], np.arange(8) / 8)
    assert np.allclose(p[:, 1:], sequences.points("halton", 8, 2), atol=1e-7)


def _star_discrepancy_2d(p, grid=64):
    """Max |empirical - volume| over anchored boxes on a grid (a lower bound of D*)."""
    t = np.arange(1, grid + 1) / grid
    inside = (p[:, 0][:, None, None] < t[None, :, None]) & (p[:, 1][:, None, None] < t[None, None, :])
    return np.abs(inside.mean(axis=0) - np.outer(t, t)).max()


@pytest.mark.parametrize("sequence", ["halton", "faure", "sobol"])
def test_scrambled_sequences_stay_low_discrepancy_and_depend_on_seed(sequence):
    a = sequences.points(sequence, 1024, 2, scramble=True, seed=budget.seed(1))
    b = sequences.points(sequence, 1024, 2, scramble=True, seed=budget.seed(2))
    r = sequences.points("independent", 1024, 2, seed=budget.seed(1))
    assert not np.allclose(a, b)
    assert np.allclose(a, sequences.points(sequence, 1024, 2, scramble=True, seed=budget.seed(1)))   # reproducible
    assert _star_discrepancy_2d(a) < 0.5 * _star_discrepancy_2d(r)


def test_owen_scrambled_sobol_keeps_stratification():
    p = sequences.points("sobol", 256, 2, scramble=True, seed=budget.seed(9))
    cells = (np.floor(p[:, 0] * 16) * 16 + np.floor(p[:, 1] * 16)).astype(int)
    assert len(np.unique(cells)) == 256          # (0, 8, 2)-net: one point per 1/16 x 1/16 cell


def test_cranley_patterson_rotation():
    p = sequences.points("halton", 64, 2)
    r = sequences.points("halton", 64, 2, rotate=True, seed=budget.seed(4))
    shift = (r - p) % 1.0
    assert np.allclose(shift, shift[0], atol=1e-6) and np.all(r < 1) and np.all(r >= 0)


def test_independent_is_uniform_and_independent_across_dims():
    n = 200000
    p = sequences.points("independent", n, 2, seed=budget.seed(5))
    budget.close(p.mean(axis=0), 0.5, np.sqrt(1 / 12 / n), what="mean")
    budget.close(np.corrcoef(p.T)[0, 1], 0.0, 1 / np.sqrt(n), what="correlation across dimensions")


@pytest.mark.parametrize("sequence, dim", [("halton", 256), ("faure", 1000), ("sobol", 1024), ("sobol", -1)])
def test_dimension_over_the_table_is_refused(sequence, dim):
    with pytest.raises(sequences.DimensionError, match="dim=%d is outside" % dim):
        sequences.sample(sequence, mi.UInt32([0, 1]), dim)


def test_unknown_sequence():
    with pytest.raises(ValueError, match="sequence='niederreiter'"):
        sequences.sample("niederreiter", mi.UInt32([0]), 0)


def test_one_hash_for_ints_and_arrays():
    """sequences.hash32 is the package's one hash (seeds.hash32 is it): ints and mi.UInt32
    lanes give equal results, and the integrators' streams keep their value."""
    from mi_plugins.base import seeds
    assert seeds.hash32 is sequences.hash32
    values = budget.rng(11).integers(0, 1 << 32, size=(64, 3))
    lanes = np.array(sequences.hash32(*(mi.UInt32(values[:, i].astype(np.uint32)) for i in range(3))))
    assert list(lanes) == [sequences.hash32(*v) for v in values.tolist()]
    assert np.array(sequences.hash32(mi.UInt32(values[:, 0].astype(np.uint32)), int(values[0, 1])))[0] == \
        sequences.hash32(*values[0, :2].tolist())
    assert seeds.stream(1, "camera") == 0x648F9C1E          # as before sequences.hash32 replaced seeds.hash32


def test_independent_is_one_pcg32_stream_per_point():
    """Number d of point i is number d of the PCG32 stream i, whatever the lane."""
    idx = mi.UInt32(budget.rng(12).permutation(64).astype(np.uint32))
    rng = mi.PCG32()
    rng.seed(mi.UInt64(sequences.hash32(budget.seed(3), 0x1D)), mi.UInt64(idx))
    for d in range(5):
        assert np.array_equal(np.array(sequences.independent(idx, d, seed=budget.seed(3))), np.array(rng.next_float32()))
    assert np.array(sequences.independent(mi.UInt32([7]), 1000, seed=budget.seed(3)))[0] == \
        np.array(sequences.independent(mi.UInt32([5, 7]), mi.UInt32([3, 1000]), seed=budget.seed(3)))[1]


@pytest.mark.parametrize("sequence", ["halton", "faure", "sobol", "hammersley", "lcg", "independent"])
def test_jit_dimension_and_per_lane_seed_give_the_points_of_int_arguments(sequence):
    """One implementation: per-lane dimensions and seeds (as the samplers call it) give
    exactly the numbers of int dimensions and seeds (points(), qmc_lighttrace)."""
    n, dims, seeds = 64, 5, [budget.seed(21), budget.seed(22)]
    lane = np.arange(n * dims * len(seeds))
    index, dim, which = lane % n, (lane // n) % dims, lane // (n * dims)
    kw = dict(dims=dims, n=n, scramble=True, rotate=True)
    jit = np.array(sequences.sample(sequence, mi.UInt32(index), mi.UInt32(dim),
                              seed=mi.UInt32(np.array(seeds, dtype=np.uint32)[which]), **kw))
    ints = np.concatenate([np.array(sequences.sample(sequence, dr.arange(mi.UInt32, n), d, seed=s, **kw))
                           for s in seeds for d in range(dims)])
    assert np.array_equal(jit, ints)
    assert np.array_equal(sequences.points(sequence, n, dims, scramble=True, seed=seeds[0], rotate=True),
                          ints[:n * dims].reshape(dims, n).T)


@pytest.mark.parametrize("sequence, dim", [("halton", 0), ("halton", 2), ("halton", 5), ("faure", 3), ("faure", 5)])
def test_digit_scrambles_keep_the_b_adic_strata(sequence, dim):
    """Random digit permutations (Halton) and Faure's permutation + digit shifts permute
    digits: the first b^2 points still fill the b^2 intervals of length 1/b^2 once each;
    and Faure's scramble is exactly Faure's permutation followed by a shift mod b."""
    b = int(sequences.primes(8)[dim])
    x = sequences.points(sequence, b * b, dim + 1, scramble=True, seed=budget.seed(31))[:, dim]
    assert sorted(np.floor(x * b * b).astype(int)) == list(range(b * b))
    if sequence == "faure":
        shift = (np.floor(x[:b] * b).astype(int) - sequences.faure_permutation(b)) % b
        assert np.all(shift == shift[0])


class _Chi2:
    """A chi-square test of observed counts against uniform frequencies, with the
    run(alpha) interface of mitsuba.chi2.ChiSquareTest (for budget.chi2)."""

    def __init__(self, counts):
        self.counts = np.asarray(counts, dtype=np.float64)

    def run(self, alpha):
        import scipy.stats
        return scipy.stats.chisquare(self.counts).pvalue >= alpha


def test_halton_digit_permutations_are_pairwise_uniform_over_seeds():
    """The justification of hashed affine digit permutations: over seeds, the images
    (pi(0), pi(1)) of two digits are uniform over the b (b - 1) distinct pairs, as for
    uniformly random permutations (so every integrand has the same variance)."""
    b, seeds = 7, 20000
    first_digit = lambda i, s: np.floor(np.array(sequences.halton(mi.UInt32(np.full(seeds, i, dtype=np.uint32)), 3,
                                                             scramble=True, seed=mi.UInt32(s))) * b).astype(int)
    s = (np.arange(seeds) + budget.seed(41) * seeds).astype(np.uint32)
    p0, p1 = first_digit(0, s), first_digit(1, s)
    assert np.all(p0 != p1)
    pairs = np.bincount(p0 * b + p1, minlength=b * b).reshape(b, b)
    assert budget.chi2(_Chi2(pairs[~np.eye(b, dtype=bool)]))


@pytest.mark.parametrize("sequence", ["halton", "faure", "sobol", "hammersley"])
def test_scrambled_points_are_uniform_over_seeds(sequence):
    """Each scramble makes every point uniform: point 0 (unscrambled 0 in every
    dimension) over many seeds has mean 1/2 and variance 1/12."""
    seeds = 1 << 14
    s = mi.UInt32((np.arange(seeds) + budget.seed(51) * seeds).astype(np.uint32))
    for dim in (1, 4, 40):
        x = np.array(sequences.sample(sequence, dr.zeros(mi.UInt32, seeds), dim, n=2, scramble=True, seed=s),
                     dtype=np.float64)
        budget.close(x.mean(), 0.5, np.sqrt(1 / 12 / seeds), what="%s dim %d mean" % (sequence, dim))
        budget.close(x.var(), 1 / 12, np.sqrt(1 / 180 / seeds), what="%s dim %d variance" % (sequence, dim))
