"""The `padded_sobol` sampler (user reference: the class docstring).

Padding: every call of ``next_1d`` / ``next_2d`` is its own *padded dimension*. It takes
the first one or two coordinates of the Sobol sequence (a (0, 2)-sequence: any 2^m
consecutive aligned points form a (0, m, 2)-net, stratified in every elementary
interval of area 2^-m), Owen-scrambled with a key of its own (pixel, padded dimension,
seed), at a sample index shuffled by a random permutation of the pixel's N indices with
the same key. The shuffle pairs the strata of different padded dimensions at random, so
no two dimensions are correlated; the scramble makes every point uniform on [0, 1)^2.
This is how production renderers sample (pbrt-v4's ``PaddedSobolSampler``), and what
Mitsuba's ``multijitter`` does with correlated multi-jittered patterns instead of
scrambled nets. The keys are hashed (:func:`mi_plugins.base.sequences.hash32`): neighbouring
dimensions get unrelated permutations.

Subclasses change where the index comes from (``zsobol``: one global index over the
image in z-order) through :meth:`PaddedSobolSampler._index_and_key`, or the point set
of each padded dimension (``lattice``, ``cmj``) through :meth:`PaddedSobolSampler._points`.
"""
import mitsuba as mi

from mi_plugins.base import sequences
from mi_plugins.samplers.sequence_sampler import SequenceSampler, reference


class PaddedSobolSampler(SequenceSampler):
    __doc__ = reference(
        'padded_sobol', 'padded, Owen-scrambled Sobol points', None,
        'Every ``next_1d`` / ``next_2d`` call draws from its own Owen-scrambled 2D Sobol net (the first two Sobol '
        'dimensions, a (0, 2)-sequence), with its own random shuffle of the pixel\'s samples: every pair of '
        'dimensions a path uses together is stratified as a (0, m, 2)-net, and no dimension is correlated with '
        'another. Powers of two for ``sample_count`` give complete nets; other counts are unbiased, less '
        'stratified.')
    sequence = "sobol"
    has_scramble = False

    def _index_and_key(self):
        """(point index, scramble key) of each lane for the current padded dimension."""
        key = sequences.hash32(self.pixel, self.dimension, self.base_seed)
        return mi.permute_kensler(self.sample_index, int(self.sample_count()), key), key

    def _points(self, index, key, coords):
        """The ``coords`` coordinates of point ``index`` of the dimension's set (keyed by ``key``)."""
        return [sequences.sample("sobol", index, c, scramble=True, seed=key) for c in range(coords)]

    def _draw(self, coords):
        index, key = self._index_and_key()
        values = self._points(index, key, coords)
        self.dimension += 1
        return values

    def next_1d(self, active=True):
        return self._draw(1)[0]

    def next_2d(self, active=True):
        return mi.Point2f(*self._draw(2))
