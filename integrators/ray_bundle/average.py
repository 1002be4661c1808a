"""``ray_bundle``'s ``average_diffuse``: per-triangle averages of purely diffuse patches.

A patch whose BSDF is purely diffuse reflects the same radiance in every direction, so
every chain's value in every averaged iteration estimates the same number: their average
over chains and iterations (O(triangles) memory) replaces the chain's value where the
final gathering reads such a patch. With the 'gather' estimate it averages what the
gathered point does not add itself (the reflected radiance R, or with ``first_shot`` and
``gather_nee=false`` everything but the emission); with 'patch' the incoming radiance
weight * sum_j A(i,j,+-d) L[j] / A_i. Only front sides are stored (the bundles exchange
radiance between front sides).
"""
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.render.frame import SPLAT_MODE
from mi_plugins.integrators.ray_bundle.direct import purely_diffuse


@dataclass
class AverageState:
    """Per-triangle sums (one list entry per order) and counts."""
    sums: list
    count: mi.Float


class DiffuseAverage:
    """``orders``: entries per patch (one per bounce order with a finite depth)."""

    def __init__(self, layout, estimate, weight, orders=1):
        table = layout.table
        diffuse = purely_diffuse(table)
        self.covers_all = bool(np.all(diffuse))
        self.layout, self.estimate, self.weight = layout, estimate, weight
        self.mask = mi.Bool(diffuse)
        self.state = AverageState([dr.zeros(mi.Color3f, table.count) for _ in range(orders)],
                                  dr.zeros(mi.Float, table.count))
        self.reset()

    def reset(self):
        """Forget every iteration added (a burn-in that goes on)."""
        st = self.state
        st.sums = [dr.zeros(mi.Color3f, dr.width(s)) for s in st.sums]
        st.count = dr.zeros(mi.Float, dr.width(st.count))
        dr.make_opaque(st.sums, st.count)

    def numpy(self):
        """(sums (K, 3), counts (K,)) as float64 numpy arrays (all orders summed)."""
        total = sum(self.state.sums[1:], self.state.sums[0])
        sums = np.stack([np.array(c, dtype=np.float64) for c in (total.x, total.y, total.z)], axis=1)
        return sums, np.array(self.state.count, dtype=np.float64)

    def load(self, sums, counts):
        """Replace the averages by given sums (K, 3) and counts (K,), e.g. summed over the
        chain tasks of a distributed render (unbounded depth: one order)."""
        sums = np.asarray(sums, dtype=np.float64)
        self.state.sums = [mi.Color3f(*(mi.Float(sums[:, c]) for c in range(3)))]
        self.state.count = mi.Float(np.asarray(counts, dtype=np.float64))

    def is_averaged(self, tri, active):
        return dr.gather(mi.Bool, self.mask, tri, active)

    def mean(self, tri, active, lo=0, hi=None):
        """The average of the orders ``lo`` .. ``hi`` (per lane; None: all) of patch ``tri``."""
        st = self.state
        total = mi.Color3f(0.0)
        for k in range(lo, len(st.sums)):
            use = active if hi is None else mi.Bool(active) & (mi.Int32(k) <= hi)
            total += dr.select(use, dr.gather(mi.Color3f, st.sums[k], tri, use), 0.0)
        return total / dr.maximum(dr.gather(mi.Float, st.count, tri, active), 1.0)

    def add(self, dirs, radiance, incoming):
        """Add one iteration of every chain: ``radiance`` (per order, per lane, every side)
        of the side each patch shows, or the ``incoming`` power (per order)."""
        layout, st = self.layout, self.state
        slot = dr.arange(mi.UInt32, layout.slots)
        tri, chain = slot % layout.count, slot // layout.count
        if self.estimate == "patch":
            area = dr.maximum(dr.gather(mi.Float, layout.table.area, tri), 1e-30)
            values, count = [], mi.Float(1.0)
            for inc in incoming:
                value = mi.Color3f(0.0)
                for side in range(layout.sides):
                    value += dr.gather(mi.Color3f, inc, layout.slot_of(tri, chain, side))
                values.append(value * (self.weight / area))
        else:
            cos_d = dr.dot(dr.gather(mi.Normal3f, layout.table.normal, tri), dr.gather(mi.Vector3f, dirs, chain))
            values = []
            for r in radiance:
                front = dr.gather(mi.Color3f, r, slot)
                if layout.sides == 1:   # only +d: the patch shows its front to half of the directions
                    values.append(dr.select(cos_d > 0, front, 0.0))
                else:
                    values.append(dr.select(cos_d > 0, front, dr.gather(mi.Color3f, r, slot + layout.slots)))
            count = dr.select(cos_d > 0, 1.0, 0.0) if layout.sides == 1 else dr.select(cos_d != 0, 1.0, 0.0)
        for k, value in enumerate(values):
            dr.scatter_add(st.sums[k], value, tri, mode=SPLAT_MODE)
        dr.scatter_add(st.count, count, tri, mode=SPLAT_MODE)
