"""The `faure` sampler (user reference: the class docstring)."""
from mi_plugins.base import sequences
from mi_plugins.samplers.sequence_sampler import SequenceSampler, reference


class FaureSampler(SequenceSampler):
    __doc__ = reference('faure', "Halton sequence with Faure's digit permutations",
                        "Faure's permutation followed by a random digit shift per dimension and digit position")
    sequence = "faure"
    max_dim = sequences.max_dim(sequence)
