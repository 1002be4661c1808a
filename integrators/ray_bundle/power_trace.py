"""The chains' total power per averaged iteration of ``ray_bundle``, for its burn-in.

The image averages the iterations after the burn-in. Started from the source term, a
chain's radiance grows toward the solution like P_m = P - c lambda^m (lambda: the share of
the power the scene reflects, the paper's contraction ratio, eq. 20), so an average taken
too early is too dark: an albedo-1 room of ``separable`` BSDFs with ``directional_area``
emitters gives 0.110 instead of 0.483 at the default 16 iterations. :class:`PowerTrace`
records every averaged iteration's total power of all chains, sum over lanes of area x
luminance of L (and of its reflected part R), with one reduction per iteration and no
host read; :func:`mi_plugins.render.burn_in.verdict` judges it.
"""
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np


@dataclass
class TraceState:
    values: mi.Float       # per averaged iteration: [sum L, sum R]


class PowerTrace:
    """Per averaged iteration of the current window: the chains' total power."""

    def __init__(self, layout, capacity):
        self.layout, self.capacity = layout, max(int(capacity), 1)
        self.state = TraceState(dr.zeros(mi.Float, 2 * self.capacity))
        dr.make_opaque(self.state.values)
        side, tri, _ = layout.lane_parts()
        self.area = dr.gather(mi.Float, layout.table.area, tri)

    def reset(self):
        self.state.values = dr.zeros(mi.Float, 2 * self.capacity)
        dr.make_opaque(self.state.values)

    def record(self, state, index):
        """Add iteration ``index`` (an opaque UInt32 inside the window) of ``state``."""
        total = sum(state.L[1:], state.L[0])
        power = dr.sum(mi.luminance(total) * self.area)
        # (the environment's light reflected once arrives in full from the first iteration:
        # a source of the model, not a part that grows)
        reflected = dr.sum(mi.luminance(state.R - state.sky) * self.area)
        dr.scatter(self.state.values, power, 2 * index)
        dr.scatter(self.state.values, reflected, 2 * index + 1)

    def numpy(self, count):
        v = np.array(self.state.values, dtype=np.float64).reshape(-1, 2)[:count]
        return v[:, 0], v[:, 1]
