"""``ray_bundle``'s first-shot source of purely diffuse patches, shared by all chains.

A purely diffuse patch reflects its direct light equally in every direction, so every
chain's source term of that patch, in every iteration, estimates one number per patch
side. :class:`SharedDirect` estimates it once per patch side and iteration (one light
and one BSDF sample, MIS, at a uniformly random point of the patch) and hands every
chain the running mean over the iterations so far: O(patches) shadow rays per
iteration instead of O(chains x patches x sides), and a source whose noise falls as the
render goes on. Unbiased: every iteration's estimate is, and the running mean is
independent of the bundles' random directions and lines that transport it. Patches of
other BSDFs keep a per-lane estimate (their reflected direct light depends on the
direction).
"""
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import seeds
from mi_plugins.light.direct import direct_light, needs_bsdf_sample


def diffuse_only(shape):
    """True when ``shape`` has a BSDF with only diffuse reflection."""
    bsdf = shape.bsdf()
    return bsdf is not None and (int(bsdf.flags()) & int(mi.BSDFFlags.All)) == int(mi.BSDFFlags.DiffuseReflection)


def purely_diffuse(table):
    """numpy bool per patch of ``table``: its shape's BSDF has only diffuse reflection."""
    return np.array([diffuse_only(shape) for shape in table.meshes], dtype=bool)[table.shape_index_np]


def direct_light_mis(scene, si, bsdf, rng, active, ctx=None):
    """Direct light at ``si`` toward ``si.wi``: one light sample, and where it needs one
    (near emitting shapes, BSDFs that are not purely diffuse: ``sampling.needs_bsdf_sample``)
    one BSDF sample too, MIS (``ctx``: the lobes to cover, default all)."""
    light_sample = mi.Point2f(rng.next_float32(), rng.next_float32())
    bsdf_sample = (rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()))
    return direct_light(scene, si, bsdf, light_sample, active, bsdf_sample, ctx,
                        mis=needs_bsdf_sample(scene, si, bsdf))


@dataclass
class DirectState:
    """The running sums of :class:`SharedDirect` and its random stream."""
    sum: mi.Color3f       # sum of the iterations' estimates, per patch side
    count: mi.Float       # iterations estimated (one opaque value)
    rng: mi.PCG32


class SharedDirect:
    """Running mean of the direct light every purely diffuse patch side reflects."""

    def __init__(self, scene, table, seed):
        self.scene, self.table = scene, table
        diffuse = purely_diffuse(table)
        self.covers_all, self.any = bool(np.all(diffuse)), bool(np.any(diffuse))
        self.mask = mi.Bool(diffuse)
        self.state = DirectState(dr.zeros(mi.Color3f, table.count), dr.opaque(mi.Float, 0.0),
                                 seeds.pcg(table.count, seed, "direct"))
        dr.make_opaque(self.state.sum)

    def update(self):
        """One more estimate per diffuse patch side (seen from its own side's normal),
        evaluated at once (one kernel: the chains gather from the sums)."""
        if not self.any:
            return
        table, st = self.table, self.state
        tri = dr.arange(mi.UInt32, table.count)
        sample = mi.Point2f(st.rng.next_float32(), st.rng.next_float32())
        si = table.surface_interaction(tri, sample, table.normal)
        st.sum = st.sum + direct_light_mis(self.scene, si, si.bsdf(), st.rng, self.mask)
        st.count = st.count + 1.0
        dr.eval(st.sum, st.count, st.rng)

    def mean(self, tri, active=True):
        """The running mean of patch ``tri`` (zero where it is not purely diffuse)."""
        return dr.gather(mi.Color3f, self.state.sum, tri, active) / dr.maximum(self.state.count, 1.0)

    def is_shared(self, tri):
        return dr.gather(mi.Bool, self.mask, tri)
