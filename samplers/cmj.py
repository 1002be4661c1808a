"""The `cmj` sampler (user reference: the class docstring).

Each padded dimension (every ``next_1d`` / ``next_2d`` call, as in ``padded_sobol``) is
Kensler's correlated multi-jittered pattern (Pixar technical memo 13-01, 2013) of the
pixel's N = m x n samples: sample s (the pixel's shuffled index) lies in cell
(s mod m, s div m) of an m x n grid, and inside its cell in the sub-column given by a
permutation of its row and the sub-row given by a permutation of its column, jittered:

    x = (s mod m + (pi_y(s div m) + jx) / n) / m,   y = (s div m + (pi_x(s mod m) + jy) / m) / n.

Every cell holds one point and each axis is stratified into N intervals; using one
permutation per axis for all rows (columns) is the "correlated" part, which spreads the
points more evenly than independent shuffles. A ``next_1d`` call is the shuffled index
jittered in its 1/N interval. m is the largest divisor of N not above sqrt(N) (N prime:
m = 1, Latin hypercube in 2D).

This is the pattern of Mitsuba's ``multijitter`` sampler; the difference is the seeding.
``multijitter`` seeds dimension d with base + d, which couples the dimensions of a sample
(the samplers section of the README and ``docs/samplers.md``); here every permutation,
shuffle and jitter is keyed by a hash of (pixel, padded dimension, seed), so the
numbers of a sample are independent and the sampler is unbiased.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.base import sequences
from mi_plugins.samplers.padded_sobol import PaddedSobolSampler
from mi_plugins.samplers.sequence_sampler import reference


def grid(n):
    """(m, n // m): the cells of the 2D pattern of ``n`` samples, m the largest divisor <= sqrt(n)."""
    m = max(d for d in range(1, int(n ** 0.5) + 1) if n % d == 0)
    return m, n // m


class CMJSampler(PaddedSobolSampler):
    __doc__ = reference(
        'cmj', 'padded, correlated multi-jittered patterns', None,
        'Every ``next_1d`` / ``next_2d`` call draws from its own correlated multi-jittered pattern (Kensler 2013: '
        'one point per cell of an m x n grid, each axis stratified into N intervals) in its own random order: '
        'the pattern of Mitsuba\'s ``multijitter`` with every dimension keyed independently, so it is unbiased '
        'where ``multijitter`` couples the numbers of a sample. Best with a ``sample_count`` that is a square or has '
        'a divisor near its square root (a prime count gives a 2D Latin hypercube).')

    def _points(self, index, key, coords):
        n = int(self.sample_count())
        jitter = [sequences.to_unit(sequences.hash32(key, index, 0x717 + c)) for c in range(coords)]
        if coords == 1:
            return [(mi.Float(index) + jitter[0]) * (1.0 / n)]
        m, rows = grid(n)
        column, row = index % m, index // m
        sub_column = mi.permute_kensler(row, rows, sequences.hash32(key, 0xC01)) if rows > 1 else dr.zeros(mi.UInt32)
        sub_row = mi.permute_kensler(column, m, sequences.hash32(key, 0x120)) if m > 1 else dr.zeros(mi.UInt32)
        return [(mi.Float(column) + (mi.Float(sub_column) + jitter[0]) * (1.0 / rows)) * (1.0 / m),
                (mi.Float(row) + (mi.Float(sub_row) + jitter[1]) * (1.0 / m)) * (1.0 / rows)]
