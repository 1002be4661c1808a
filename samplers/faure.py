"""``faure``: Halton sequence with Faure's digit permutations (Keller's report).

Parameters as ``halton``: ``sample_count`` (int >= 1, default 4), ``scramble`` (bool,
default true: Faure's permutation followed by a random digit shift per pixel, dimension
and digit position, the scramble of ``mi_plugins.qmc``), ``seed`` (int, default 0:
selects the randomisation together with the render seed).
"""
from mi_plugins import qmc
from mi_plugins.samplers.sequence_sampler import SequenceSampler


class FaureSampler(SequenceSampler):
    sequence = "faure"
    max_dim = qmc.max_dim(sequence)
