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
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.integrators.core import SPLAT_MODE
from mi_plugins.integrators.ray_bundle.direct import purely_diffuse


class DiffuseAverage:

    def __init__(self, layout, estimate, weight):
        table = layout.table
        diffuse = purely_diffuse(table)
        self.covers_all = bool(np.all(diffuse))
        self.layout, self.estimate, self.weight = layout, estimate, weight
        self.mask = mi.Bool(diffuse)
        self.sum = dr.zeros(mi.Color3f, table.count)
        self.count = dr.zeros(mi.Float, table.count)

    def state(self):
        return self.sum, self.count

    def numpy(self):
        """(sums (K, 3), counts (K,)) as float64 numpy arrays."""
        sums = np.stack([np.array(c, dtype=np.float64) for c in (self.sum.x, self.sum.y, self.sum.z)], axis=1)
        return sums, np.array(self.count, dtype=np.float64)

    def load(self, sums, counts):
        """Replace the averages by given sums (K, 3) and counts (K,), e.g. summed over the
        chain tasks of a distributed render."""
        sums = np.asarray(sums, dtype=np.float64)
        self.sum = mi.Color3f(*(mi.Float(sums[:, c]) for c in range(3)))
        self.count = mi.Float(np.asarray(counts, dtype=np.float64))

    def is_averaged(self, tri, active):
        return dr.gather(mi.Bool, self.mask, tri, active)

    def mean(self, tri, active):
        return (dr.gather(mi.Color3f, self.sum, tri, active)
                / dr.maximum(dr.gather(mi.Float, self.count, tri, active), 1.0))

    def add(self, dirs, radiance, incoming):
        """Add one iteration of every chain: ``radiance`` (per lane, every side) of the
        side each patch shows, or the ``incoming`` power."""
        layout = self.layout
        slot = dr.arange(mi.UInt32, layout.slots)
        tri, chain = slot % layout.count, slot // layout.count
        if self.estimate == "patch":
            area = dr.maximum(dr.gather(mi.Float, layout.table.area, tri), 1e-30)
            value = mi.Color3f(0.0)
            for side in range(layout.sides):
                value += dr.gather(mi.Color3f, incoming, layout.slot_of(tri, chain, side))
            value, count = value * (self.weight / area), mi.Float(1.0)
        else:
            cos_d = dr.dot(dr.gather(mi.Normal3f, layout.table.normal, tri), dr.gather(mi.Vector3f, dirs, chain))
            front = dr.gather(mi.Color3f, radiance, slot)
            if layout.sides == 1:   # only +d: the patch shows its front to half of the directions
                value, count = dr.select(cos_d > 0, front, 0.0), dr.select(cos_d > 0, 1.0, 0.0)
            else:
                back = dr.gather(mi.Color3f, radiance, slot + layout.slots)
                value, count = dr.select(cos_d > 0, front, back), dr.select(cos_d != 0, 1.0, 0.0)
        dr.scatter_add(self.sum, value, tri, mode=SPLAT_MODE)
        dr.scatter_add(self.count, count, tri, mode=SPLAT_MODE)
