"""How a package integrator's render splits across processes: the typed declaration a
plugin returns from ``distributed_split(scene, spp)`` (None: independent passes, as every
other integrator). :mod:`mi_plugins.distributed.plan` builds the tasks from the
declaration alone and never reads the plugin's own settings.
"""
from dataclasses import dataclass


@dataclass(frozen=True)
class ParticleRanges:
    """A first phase of ``paths`` particle paths of one sequence, split into disjoint
    contiguous ranges whose per-patch deposits are summed in range order; then passes that
    each render with the sum (``trace_particles``, ``render_with_particles``)."""
    paths: int


@dataclass(frozen=True)
class ChainGroups:
    """A first phase of ``chains`` chains split into groups (each with its own seed, through
    every iteration) whose per-patch averages are summed in group order; then
    ``final_passes`` final-gathering passes, split into groups and merged by their pass
    counts (``chain_averages``, ``gather_from``)."""
    chains: int
    final_passes: int
