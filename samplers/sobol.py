"""``sobol``: Sobol sequence sampler (Joe-Kuo direction numbers, 1024 dimensions).

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
     - per-pixel hash-based Owen scrambling (independent randomisation per pixel; the
       scramble of ``mi_plugins.qmc``)
   * - seed
     - int, 0 .. 2^32 - 1
     - 0
     - selects the randomisation together with the render seed (``mi.render(seed=...)``):
       another seed, other images; 0 = the render seed alone

Use powers of two for ``sample_count``: the first 2^m Sobol points are a (t, m, s)-net.
"""
from mi_plugins import qmc
from mi_plugins.samplers.sequence_sampler import SequenceSampler


class SobolSampler(SequenceSampler):
    sequence = "sobol"
    max_dim = qmc.max_dim(sequence)
