"""``halton``: Halton sequence sampler (radical inverses in the first 256 primes).

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Default
     - Description
   * - sample_count
     - int, 1 .. 2^32 - 1
     - 4
     - samples per pixel (``mi.render(spp=...)`` overrides it)
   * - scramble
     - bool
     - true
     - random digit permutations (one per pixel, dimension and digit position: the
       scramble of ``mi_plugins.qmc``), so every pixel has its own randomisation; the
       permutations also remove the correlations of plain Halton in high dimensions
   * - seed
     - int, 0 .. 2^32 - 1
     - 0
     - selects the randomisation together with the render seed (``mi.render(seed=...)``):
       another seed, other images; 0 = the render seed alone
"""
from mi_plugins import qmc
from mi_plugins.samplers.sequence_sampler import SequenceSampler


class HaltonSampler(SequenceSampler):
    sequence = "halton"
    max_dim = qmc.max_dim(sequence)
