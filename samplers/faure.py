"""``faure``: Halton sequence with Faure's digit permutations (Keller's report).

Parameters as ``halton``: ``sample_count`` (int >= 1, default 4), ``scramble`` (bool,
default true: per-pixel Cranley-Patterson rotation on top of Faure's deterministic
permutations), ``seed`` (int, default 0: selects the randomisation together
with the render seed).
"""
from mi_plugins.samplers.halton import HaltonSampler


class FaureSampler(HaltonSampler):
    sequence = "faure"
    faure = True
