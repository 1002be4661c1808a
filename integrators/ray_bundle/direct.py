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
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import seeds
from mi_plugins.sampling import direct_light


def diffuse_only(shape):
    """True when ``shape`` has a BSDF with only diffuse reflection."""
    bsdf = shape.bsdf()
    return bsdf is not None and (int(bsdf.flags()) & int(mi.BSDFFlags.All)) == int(mi.BSDFFlags.DiffuseReflection)


def purely_diffuse(table):
    """numpy bool per patch of ``table``: its shape's BSDF has only diffuse reflection."""
    return np.array([diffuse_only(shape) for shape in table.meshes], dtype=bool)[table.shape_index_np]


def direct_light_mis(scene, si, bsdf, rng, active):
    """Direct light at ``si`` toward ``si.wi``: one light and one BSDF sample, MIS."""
    light_sample = mi.Point2f(rng.next_float32(), rng.next_float32())
    bsdf_sample = (rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()))
    return direct_light(scene, si, bsdf, light_sample, active, bsdf_sample)


class SharedDirect:
    """Running mean of the direct light every purely diffuse patch side reflects."""

    def __init__(self, scene, table, seed):
        self.scene, self.table = scene, table
        diffuse = purely_diffuse(table)
        self.covers_all, self.any = bool(np.all(diffuse)), bool(np.any(diffuse))
        self.mask = mi.Bool(diffuse)
        self.rng = seeds.pcg(table.count, seed, "direct")
        self.sum = dr.zeros(mi.Color3f, table.count)   # sum of the iterations' estimates
        self.count = mi.Float(0.0)                     # iterations estimated (opaque: one kernel)
        dr.make_opaque(self.count)

    def state(self):
        return self.sum, self.count, self.rng.state

    def update(self):
        """One more estimate per diffuse patch side (seen from its own side's normal)."""
        if not self.any:
            return
        table = self.table
        tri = dr.arange(mi.UInt32, table.count)
        sample = mi.Point2f(self.rng.next_float32(), self.rng.next_float32())
        si = table.surface_interaction(tri, sample, table.normal)
        self.sum += direct_light_mis(self.scene, si, si.bsdf(), self.rng, self.mask)
        self.count += 1.0

    def mean(self, tri, active=True):
        """The running mean of patch ``tri`` (zero where it is not purely diffuse)."""
        return dr.gather(mi.Color3f, self.sum, tri, active) / dr.maximum(self.count, 1.0)

    def is_shared(self, tri):
        return dr.gather(mi.Bool, self.mask, tri)
