"""The `sobol` sampler (user reference: the class docstring)."""
from mi_plugins.base import sequences
from mi_plugins.samplers.sequence_sampler import SequenceSampler, reference


class SobolSampler(SequenceSampler):
    __doc__ = reference('sobol', 'Sobol sequence, Joe-Kuo direction numbers, 1024 dimensions',
                        'hash-based Owen scrambling',
                        'Use powers of two for ``sample_count``: the first 2^m Sobol points are a (t, m, s)-net.')
    sequence = "sobol"
    max_dim = sequences.max_dim(sequence)
