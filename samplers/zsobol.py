"""The `zsobol` sampler (user reference: the class docstring).

The image is one sequence: pixel p's sample i has the global index
g = p * 2^m + i (2^m >= N samples per pixel), the pixels in the order of Mitsuba's
wavefront. For each padded dimension the base-4 digits of g are permuted, from the top
digit down, each by one of the 24 permutations of {0, 1, 2, 3} chosen by a hash of the
digits above it, the dimension and the seed (a lone bottom base-2 digit, when m is odd,
is flipped the same way); the point is then coordinate 0 (and 1) of the Sobol sequence
at the permuted index, Owen-scrambled with one key per dimension for the whole image.

Why: a pixel's 2^m indices stay one aligned block after the permutation, so its points
are a (0, m, 2)-net as in ``padded_sobol``; and the blocks of neighbouring pixels are
complementary parts of one larger net, so the pixel errors are negatively correlated
(blue noise) and the image mean converges faster than the pixels do. The idea is Ahmed
and Wonka's screen-space sample ordering (2020) as pbrt-v4's ``ZSobolSampler`` uses it.
A Mitsuba sampler is not told the film's width, so neighbours are neighbours in the
wavefront order (along rows), not in a 2D Morton curve.
"""
import functools
import itertools

import drjit as dr
import mitsuba as mi

from mi_plugins import qmc
from mi_plugins.samplers.padded_sobol import PaddedSobolSampler
from mi_plugins.samplers.sequence_sampler import reference


@functools.lru_cache(maxsize=None)
def _permutations(variant):
    """The 24 permutations of {0, 1, 2, 3}, flattened (permutation k, digit d at 4 k + d)."""
    return mi.UInt32([d for perm in itertools.permutations(range(4)) for d in perm])


class ZSobolSampler(PaddedSobolSampler):
    __doc__ = reference(
        'zsobol', 'z-ordered Owen-scrambled Sobol points over the whole image', None,
        'Each pixel\'s points are a scrambled (0, m, 2)-net per padded dimension, as with ``padded_sobol``; '
        'the nets of neighbouring pixels (in the film\'s row order) are complementary parts of one larger net, '
        'so pixel errors are blue noise and averages over pixels converge faster. ``sample_count`` is rounded '
        'up to a power of two for the index (only the first ``sample_count`` indices are used); pixels x '
        'that power of two must not exceed 2^32.')
    plugin = "zsobol"
    sample_bits = index_bits = 0       # set by seed(): bits of the sample index and of g

    def seed(self, seed, wavefront_size=0xFFFFFFFF):
        super().seed(seed, wavefront_size)
        n = int(self.sample_count())
        self.sample_bits = (n - 1).bit_length()
        pixels = max(self.wavefront // self.per_pixel, 1)
        self.index_bits = self.sample_bits + (pixels - 1).bit_length()
        if self.index_bits > 32:
            raise ValueError("zsobol: parameter sample_count=%d is invalid together with an image of %d pixels; "
                             "valid range: pixels x 2^ceil(log2 sample_count) <= 2^32 (use padded_sobol)"
                             % (n, pixels))

    def _copy_state(self, other):
        other.sample_bits, other.index_bits = self.sample_bits, self.index_bits
        return super()._copy_state(other)

    def _index_and_key(self):
        g = (self.pixel << self.sample_bits) | self.sample_index
        key = qmc.hash32(self.dimension, self.base_seed)          # one key per dimension, whole image
        perms = _permutations(mi.variant())
        low = self.sample_bits % 2                                # a lone base-2 digit at the bottom
        index = mi.UInt32(0)
        for shift in range(low, self.index_bits, 2):             # the base-4 digits (unrolled, <= 16)
            digit = (g >> shift) & 3
            higher = g >> (shift + 2) if shift + 2 < 32 else 0
            choice = qmc.hash32(higher, key, shift) % 24
            index |= dr.gather(mi.UInt32, perms, choice * 4 + digit) << shift
        if low:
            index |= (g & 1) ^ (qmc.hash32(g >> 1, key, 0xB17) & 1)
        return index, key
