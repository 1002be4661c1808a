"""Sequences of mi_plugins.qmc against independent implementations (scipy, libc)."""
import ctypes

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import scipy.stats.qmc as sq

from mi_plugins import qmc

import budget


def test_halton_matches_scipy():
    assert np.abs(qmc.points("halton", 4096, 32) - sq.Halton(32, scramble=False).random(4096)).max() < 1e-6


@pytest.mark.parametrize("dims, n", [(64, 4096), (1024, 16)])
def test_sobol_matches_scipy_in_gray_code_order(dims, n):
    i = np.arange(n)
    gray = mi.UInt32(i ^ (i >> 1))            # scipy enumerates Sobol points in Gray-code order
    ours = np.stack([np.array(qmc.sobol(gray, d)) for d in range(dims)], axis=1)
    assert np.abs(ours - sq.Sobol(dims, scramble=False).random(n)).max() == 0.0


@pytest.mark.parametrize("dims, n", [(64, 4096), (1024, 16)])
def test_jit_dimension_sobol_matches_scipy(dims, n):
    """sobol_dynamic (the dimension a per-lane JIT value: what the samplers and
    qmc_lighttrace use) against scipy, all dimensions in one kernel."""
    i = np.arange(n)
    gray = np.repeat(i ^ (i >> 1), dims).astype(np.uint32)
    dim = np.tile(np.arange(dims), n).astype(np.uint32)
    ours = np.array(qmc.sobol_dynamic(mi.UInt32(gray), mi.UInt32(dim))).reshape(n, dims)
    assert np.abs(ours - sq.Sobol(dims, scramble=False).random(n)).max() == 0.0


def test_jit_dimension_halton_matches_scipy_and_faure_is_its_permutation():
    n, dims = 1024, 48
    index = np.repeat(np.arange(n), dims).astype(np.uint32)
    dim = np.tile(np.arange(dims), n).astype(np.uint32)
    ours = np.array(qmc.halton_dynamic(mi.UInt32(index), mi.UInt32(dim))).reshape(n, dims)
    assert np.abs(ours - sq.Halton(dims, scramble=False).random(n)).max() < 1e-6
    faure = np.array(qmc.halton_dynamic(mi.UInt32(index), mi.UInt32(dim), faure=True)).reshape(n, dims)
    assert np.abs(faure - qmc.points("faure", n, dims)).max() < 1e-6
    assert np.abs(faure[:, 0] - ours[:, 0]).max() < 1e-7          # base 2: Faure's permutation is the identity


def test_lcg_is_drand48():
    libc = ctypes.CDLL("libc.so.6")
    libc.drand48.restype = ctypes.c_double
    libc.srand48(12345)
    reference = np.array([libc.drand48() for _ in range(3 * 50)]).reshape(50, 3)
    assert np.abs(qmc.points("lcg", 50, 3, seed=12345) - reference).max() < 1e-7


def test_faure_permutations_of_the_report():
    assert list(qmc.faure_permutation(5)) == [0, 3, 2, 1, 4]
    assert list(qmc.faure_permutation(7)) == [0, 2, 5, 3, 1, 4, 6]
    for b in (2, 3, 11, 29, 97):
        assert sorted(qmc.faure_permutation(b)) == list(range(b))


def test_faure_is_permuted_halton():
    idx = mi.UInt32(np.arange(25))
    x = np.array(qmc.faure(idx, 2))  # base 5, digit permutation (0 3 2 1 4)
    i = np.arange(25)
    perm = np.array([0, 3, 2, 1, 4])
    assert np.allclose(x, perm[i % 5] / 5 + perm[(i // 5) % 5] / 25, atol=1e-7)


def test_hammersley_first_coordinate_and_rest():
    p = qmc.points("hammersley", 8, 3)
    assert np.allclose(p[:, 0], np.arange(8) / 8)
    assert np.allclose(p[:, 1:], qmc.points("halton", 8, 2), atol=1e-7)


def _star_discrepancy_2d(p, grid=64):
    """Max |empirical - volume| over anchored boxes on a grid (a lower bound of D*)."""
    t = np.arange(1, grid + 1) / grid
    inside = (p[:, 0][:, None, None] < t[None, :, None]) & (p[:, 1][:, None, None] < t[None, None, :])
    return np.abs(inside.mean(axis=0) - np.outer(t, t)).max()


@pytest.mark.parametrize("sequence", ["halton", "faure", "sobol"])
def test_scrambled_sequences_stay_low_discrepancy_and_depend_on_seed(sequence):
    a = qmc.points(sequence, 1024, 2, scramble=True, seed=budget.seed(1))
    b = qmc.points(sequence, 1024, 2, scramble=True, seed=budget.seed(2))
    r = qmc.points("independent", 1024, 2, seed=budget.seed(1))
    assert not np.allclose(a, b)
    assert np.allclose(a, qmc.points(sequence, 1024, 2, scramble=True, seed=budget.seed(1)))   # reproducible
    assert _star_discrepancy_2d(a) < 0.5 * _star_discrepancy_2d(r)


def test_owen_scrambled_sobol_keeps_stratification():
    p = qmc.points("sobol", 256, 2, scramble=True, seed=budget.seed(9))
    cells = (np.floor(p[:, 0] * 16) * 16 + np.floor(p[:, 1] * 16)).astype(int)
    assert len(np.unique(cells)) == 256          # (0, 8, 2)-net: one point per 1/16 x 1/16 cell


def test_cranley_patterson_rotation():
    p = qmc.points("halton", 64, 2)
    r = qmc.points("halton", 64, 2, rotate=True, seed=budget.seed(4))
    shift = (r - p) % 1.0
    assert np.allclose(shift, shift[0], atol=1e-6) and np.all(r < 1) and np.all(r >= 0)


def test_independent_is_uniform_and_independent_across_dims():
    n = 200000
    p = qmc.points("independent", n, 2, seed=budget.seed(5))
    budget.close(p.mean(axis=0), 0.5, np.sqrt(1 / 12 / n), what="mean")
    budget.close(np.corrcoef(p.T)[0, 1], 0.0, 1 / np.sqrt(n), what="correlation across dimensions")


@pytest.mark.parametrize("sequence, dim", [("halton", 256), ("faure", 1000), ("sobol", 1024), ("sobol", -1)])
def test_dimension_over_the_table_is_refused(sequence, dim):
    with pytest.raises(qmc.DimensionError, match="dim=%d is outside" % dim):
        qmc.sample(sequence, mi.UInt32([0, 1]), dim)


def test_unknown_sequence():
    with pytest.raises(ValueError, match="sequence='niederreiter'"):
        qmc.sample("niederreiter", mi.UInt32([0]), 0)
