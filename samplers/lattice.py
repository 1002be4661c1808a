"""The `lattice` sampler (user reference: the class docstring).

Each padded dimension (every ``next_1d`` / ``next_2d`` call, as in ``padded_sobol``) is a
rank-1 lattice of the pixel's N samples, {(i / N, (i a mod N) / N)}, Cranley-Patterson
rotated by a random shift of its own (pixel, dimension, seed) and visited in a random
order of its own. The generator a maximises the lattice's shortest vector (searched
once per N up to 4096; above, the coprime integer nearest N / golden ratio, the
Fibonacci-lattice choice). The rotation makes every point uniform on [0, 1)^2 and the
shuffles make the dimensions independent, so the sampler is unbiased; a lattice's 1D
projections are the N strata exactly and its 2D points are as evenly spread as N points
can be, which gives the lowest errors of the package's samplers on smooth
low-dimensional integrands (direct light, one bounce).
"""
import functools
import math

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import sequences
from mi_plugins.samplers.padded_sobol import PaddedSobolSampler
from mi_plugins.samplers.sequence_sampler import reference

#: largest N whose generator is searched exhaustively
SEARCH_LIMIT = 4096


@functools.lru_cache(maxsize=None)
def generator(n):
    """The lattice generator a for N = ``n`` points (see the module docstring)."""
    if n < 3:
        return 1
    if n > SEARCH_LIMIT:
        a = round(n / ((1 + 5 ** 0.5) / 2))
        return next(c for k in range(n) for c in (a + k, a - k) if 0 < c < n and math.gcd(c, n) == 1)
    i = np.arange(1, n)
    best, best_a = -1.0, 1
    for a in range(1, n // 2 + 1):
        if math.gcd(a, n) != 1:
            continue
        dx, dy = i / n, (i * a % n) / n           # every lattice vector, wrapped to the torus
        dist = np.min(np.hypot(np.minimum(dx, 1 - dx), np.minimum(dy, 1 - dy)))
        if dist > best:
            best, best_a = dist, a
    return best_a


class LatticeSampler(PaddedSobolSampler):
    __doc__ = reference(
        'lattice', 'padded, randomly shifted rank-1 lattices', None,
        'Every ``next_1d`` / ``next_2d`` call draws from its own randomly shifted rank-1 lattice of the pixel\'s '
        '``sample_count`` points, in its own random order: unbiased, exactly stratified in 1D, and the most '
        'even 2D spread; best on smooth low-dimensional integrands (measured: the lowest errors with one '
        'bounce). Counts >= 9 give useful 2D lattices (4 points lie on a diagonal).')

    def _points(self, index, key, coords):
        n = int(self.sample_count())
        offsets = (mi.UInt32(0) + index, (index * generator(n)) % n)
        values = []
        for c in range(coords):
            x = mi.Float(offsets[c]) * (1.0 / n) + sequences.to_unit(sequences.hash32(key, 0x5EED + c))
            values.append(dr.select(x >= 1.0, x - 1.0, x))
        return values
