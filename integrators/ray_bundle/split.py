"""One ``ray_bundle`` render split across tasks (used by :mod:`mi_plugins.distributed`).

With ``average_diffuse`` in a scene whose surfaces are all purely diffuse, the image is
made only by the final gathering, from the per-patch averages over all chains and
averaged iterations. Such a render splits into

1. *chain tasks*: each runs its own chains (``chains``, its own seed) through all the
   iterations and returns its averages' sums and counts per patch (:func:`run_chains`);
   summed over the tasks they are the averages of all chains, as in one render whose
   chains were grouped (each group with its own stratified direction sets);
2. *gathering tasks*: each renders ``passes`` final-gathering passes from the summed
   averages, with fresh stratified gather directions (:func:`run_gathering`); the image is
   their pass-weighted mean.

The total work equals one render's: every chain runs its burn-in once. Other renders
(non-diffuse surfaces, no ``average_diffuse``) split into independent passes instead.
"""
from dataclasses import dataclass

import numpy as np

from mi_plugins.integrators.ray_bundle.direct import diffuse_only


@dataclass
class Split:
    """A render's part (``render_task``): ``mode`` 'chains' (iterations of ``chains``
    chains, no image; the result is (sums, counts)) or 'gather' (``passes``
    final-gathering passes from ``average`` = (sums, counts), no iterations)."""
    mode: str
    chains: int = 0
    passes: int = 0
    average: tuple = None


def splits_by_chains(integ, scene):
    """True when ``integ``'s render of ``scene`` is all final gathering from averages."""
    return bool(integ.average_diffuse) and all(diffuse_only(shape) for shape in scene.shapes())


def final_passes(integ, spp):
    """Final-gathering passes of a whole render with ``spp``: one per averaged iteration."""
    return integ.iterations * int(spp) - integ.burn_in


def run_chains(integ, scene, seed, spp, chains):
    """Sums (K, 3) and counts (K,) of the diffuse averages of ``chains`` chains run for
    ``integ.iterations * spp`` iterations with render seed ``seed``."""
    return integ.render_task(scene, Split("chains", chains=int(chains)), seed=int(seed), spp=int(spp))


def run_gathering(integ, scene, sums, counts, passes, seed):
    """The image (float64) of ``passes`` final-gathering passes from the given averages."""
    image = integ.render_task(scene, Split("gather", passes=int(passes), average=(sums, counts)), seed=int(seed), spp=1)
    return np.array(image, dtype=np.float64)
