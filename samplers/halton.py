"""The `halton` sampler (user reference: the class docstring)."""
from mi_plugins.base import sequences
from mi_plugins.samplers.sequence_sampler import SequenceSampler, reference


class HaltonSampler(SequenceSampler):
    __doc__ = reference('halton', 'Halton sequence, radical inverses in the first 256 primes',
                        'random digit permutations (one per dimension and digit position; they also remove the correlations of plain Halton in high dimensions)')
    sequence = "halton"
    max_dim = sequences.max_dim(sequence)
