"""The `zsobol` sampler (user reference: the class docstring).

The image is one sequence: pixel p's sample i has the global index
g = p * 2^m + pi(i) (2^m >= N samples per pixel), the pixels in the order of Mitsuba's
wavefront and pi a random order of the pixel's samples per padded dimension (as in
``padded_sobol``: without it the scramble's nesting pairs the samples of different
dimensions in one dyadic pattern, measured 1-2 % higher errors on Bekaert's box). For
each padded dimension g is Owen-scrambled as an m + log2(pixels)-bit
number (:func:`mi_plugins.base.sequences.owen_scramble`: its top bit flipped at random, every lower
bit by a hash of the bits above it, the dimension and the seed); the point is then
coordinate 0 (and 1) of the Sobol sequence at the scrambled index, Owen-scrambled with
one key per dimension for the whole image.

Why: a pixel's 2^m indices stay one aligned block after the scramble, so its points
are a (0, m, 2)-net as in ``padded_sobol``; and the blocks of neighbouring pixels are
complementary parts of one larger net, so the pixel errors are negatively correlated
(blue noise) and the image mean converges faster than the pixels do. The idea is Ahmed
and Wonka's screen-space sample ordering (2020) as pbrt-v4's ``ZSobolSampler`` uses it.
A Mitsuba sampler is not told the film's width, so neighbours are neighbours in the
wavefront order (along rows), not in a 2D Morton curve. pbrt-v4 permutes base-4 digits
instead (one digit is a 2 x 2 quad of its Morton order); along rows that gains nothing
over the base-2 scramble, which costs one hash per call instead of a table permutation
per digit.
"""
from mi_plugins.base import sequences
from mi_plugins.samplers.padded_sobol import PaddedSobolSampler
from mi_plugins.samplers.sequence_sampler import reference


class ZSobolSampler(PaddedSobolSampler):
    __doc__ = reference(
        'zsobol', 'z-ordered Owen-scrambled Sobol points over the whole image', None,
        'Each pixel\'s points are a scrambled (0, m, 2)-net per padded dimension, as with ``padded_sobol``; '
        'the nets of neighbouring pixels (in the film\'s row order) are complementary parts of one larger net, '
        'so pixel errors are blue noise and averages over pixels converge faster. ``sample_count`` is rounded '
        'up to a power of two for the index (only the first ``sample_count`` indices are used); pixels x '
        'that power of two must not exceed 2^32.')
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
        # the pixel's samples in padded_sobol's random order of their own per dimension, so
        # that the scramble's nesting does not pair the samples of different dimensions
        order, _ = super()._index_and_key()
        g = (self.pixel << self.sample_bits) | order
        key = sequences.hash32(self.dimension, self.base_seed)          # one key per dimension, whole image
        if self.index_bits == 0:                                  # one pixel, one sample
            return g, key
        top = 32 - self.index_bits                                # g's bits at the top of the word
        return sequences.owen_scramble(g << top, sequences.hash32(key, 0x1D3)) >> top, key
