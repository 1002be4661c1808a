"""``ray_bundle``'s adaptive subdivision (``refine``): a pilot part of the solve on the
given patches measures what the lines bring to every child of every patch side
(``transfer.ChildStats``; with ``first_shot`` the direct light too, by next-event
estimation at random points of the patches); the patches inside which it varies split
(``mi_plugins.patches.refinement.choose``), and the solve goes on on the refined patches from the
pilot's state: every chain's radiance of a child is its parent's, and so is the shared
direct light's running mean. The refined part has its own burn-in (:data:`BURN_IN`: the
children's radiance is close to converged) and its averaged iterations make the solution.
"""
import numpy as np

import drjit as dr
import mitsuba as mi

from mi_plugins.patches import refinement
from mi_plugins.base import seeds
from mi_plugins.solution import patch_light
from mi_plugins.solution.child_field import field_children
from mi_plugins.integrators.ray_bundle.transfer import ChainState

#: burn-in of the refined part (its chains start from the pilot's, nearly converged)
BURN_IN = 2
#: the pilot's averaged iterations, as a share of the planned ones
PILOT_SHARE = 0.5
#: points per patch side measuring the direct light in the children (with first_shot)
DIRECT_SAMPLES = 64


def all_origins(old, new, origin):
    """For every patch of ``new`` (fronts, then backs), the patch of ``old`` it comes from
    (``origin``: the front patches')."""
    backs = np.arange(new.front_count, new.count)
    front = new.front_of_np[backs]
    return np.concatenate([origin, old.back_of_np[origin[front]]]).astype(np.int64)


def map_state(state, old_layout, new_layout, origin):
    """The chain state on the refined layout: every lane its parent patch's lane."""
    side, tri, chain = (np.array(a, dtype=np.int64) for a in new_layout.lane_parts())
    index = mi.UInt32(((side * old_layout.chains + chain) * old_layout.count + origin[tri]).astype(np.uint32))
    take = lambda values: dr.gather(mi.Color3f, values, index)
    return ChainState(state.dirs, [take(L) for L in state.L], take(state.R),
                      take(state.sky) if dr.width(state.sky) > 1 else state.sky)


def map_direct(old, new, origin):
    """The shared direct light's running mean of every refined patch side: its parent's."""
    if old is None or new is None:
        return
    index = mi.UInt32(origin.astype(np.uint32))
    new.state.sum = dr.gather(mi.Color3f, old.state.sum, index)
    new.state.count = mi.Float(old.state.count)
    dr.make_opaque(new.state.sum, new.state.count)


def choose(integ, run, scene, seed):
    """The patches of the pilot ``run`` to split: by what the lines brought to each
    child, and with ``first_shot`` (the direct light not in the bundles) by the direct
    light too, measured at DIRECT_SAMPLES points per patch side."""
    table = run.layout.table
    sums, squares = run.transport.children.numpy()
    if run.transport.first_shot:
        direct = patch_light.direct_irradiance(scene, table, seeds.stream(seed, "refine"),
                                               samples=DIRECT_SAMPLES, children=True)
        more = refinement.from_points(table, *direct[2:])
        sums, squares = sums + more[0], squares + more[1]
    min_size = integ.min_patch_size if integ.min_patch_size is not None else table.h / 4.0
    budget = integ.max_patches or refinement.DEFAULT_BUDGET * table.front_count
    return refinement.choose(table, sums, squares, integ.refine_threshold, min_size, budget, expected=field_children)
