"""Where ``qmc_lighttrace`` stores radiance, and how a stored value is written and read.

Keller's method keeps one value per patch side, so it can only store radiance that does
not depend on the direction it leaves in. That holds where the BSDF is *purely
diffuse*: its only lobe is ``DiffuseReflection`` (``diffuse``, ``twosided`` diffuse,
a ``blendbsdf`` of diffuse BSDFs, textured or not) and it is not wrapped in a
``bumpmap`` or ``normalmap`` (which make the reflection depend on the perturbed
frame). Everything else (glossy, delta, null, mixed lobes) is *non-diffuse*: particles
pass through it without leaving anything, and camera paths continue there instead of
reading (``qmc_gather``).

What a patch side stores is the *irradiance* of the shading frame, E = integral of
L |cos_sh| dw, from particles: each arrival adds its power x |cos_sh(wi)| / |cos_geo(wi)|
(the particle density over the surface follows the geometric cosine; the BSDF of
``path`` weighs incident light with the shading cosine). Reading multiplies by the BSDF
at the point read, f(v, n) = rho(x) / pi where it reflects toward v: a texture is read
at the point itself, not averaged over the patch. A side holds light that arrives
on it; it is read from the same side. Arrivals whose shading and geometric sides differ
(grazing light on meshes with vertex normals) are not stored, and a view whose sides
differ reads nothing: there ``path`` differs from the stored estimate (README).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base.arrays import jit
from mi_plugins.base import queries
from mi_plugins.patches.crowding import crowded_patches
from mi_plugins.patches.gaps import mouth_patches

#: BSDF wrappers whose reflection depends on a perturbed frame (Mitsuba class names)
VIEW_DEPENDENT_WRAPPERS = ("BumpMap", "NormalMap")


def purely_diffuse(bsdf):
    """Is ``bsdf`` (a scalar BSDF object) purely diffuse (module docstring)?"""
    if bsdf is None:
        return False
    lobes = int(bsdf.flags()) & int(mi.BSDFFlags.All)
    return lobes == int(mi.BSDFFlags.DiffuseReflection) and not (
        queries.nested_classes(bsdf) & set(VIEW_DEPENDENT_WRAPPERS))


class Surfaces:
    """Per-shape classification of a scene, for kernels: :meth:`diffuse` per hit; with the
    scene's patch ``table``, :meth:`readable` too; ``crowd_reach`` (the smooth display's):
    the crowded patches are not read either (:mod:`mi_plugins.patches.crowding`), nor those
    of ``steep`` (numpy bool per front patch: :mod:`mi_plugins.solution.steep`)."""

    def __init__(self, scene, table=None, crowd_reach=0.0, steep=None):
        unread = mouth_patches(table) | crowded_patches(table, crowd_reach) if table is not None \
            else np.zeros(0, bool)
        if steep is not None:
            unread = unread | steep
        self.table, self.any_unread = table, bool(unread.any())
        self._unread = jit(mi.UInt32, np.concatenate([unread, [False, False]]))   # (never width 1)
        shapes = list(scene.shapes())
        self.diffuse_np = np.array([purely_diffuse(s.bsdf()) for s in shapes], dtype=bool)
        ids = np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), dtype=np.int64) if shapes else \
            np.zeros(0, np.int64)
        table = np.zeros(int(ids.max()) + 1 if len(ids) else 1, dtype=np.uint32)
        table[ids] = self.diffuse_np
        self._diffuse_by_id = jit(mi.UInt32, table)

    @property
    def any_diffuse(self):
        return bool(self.diffuse_np.any())

    def diffuse(self, si, active=True):
        """Per lane: ``si`` is a valid hit of a purely diffuse surface."""
        active = mi.Bool(active) & si.is_valid()
        shape_id = dr.reinterpret_array(mi.UInt32, si.shape)
        return active & (dr.gather(mi.UInt32, self._diffuse_by_id, shape_id, active) != 0)

    def readable(self, si, active=True):
        """Per lane: :meth:`diffuse`, and not on a patch at the mouth of a narrow gap
        (:mod:`mi_plugins.patches.gaps`: its one value mixes the light trapped in the gap with the
        open side's) or, with ``crowd_reach``, on a crowded patch, or on a steep one; a camera path continues
        at the other diffuse hits, as on a glossy surface, instead of reading the stored
        light there."""
        diffuse = self.diffuse(si, active)
        if not self.any_unread:
            return diffuse
        return diffuse & (dr.gather(mi.UInt32, self._unread, self.table.patch(si), diffuse) == 0)


def geometric_cosine(si, local):
    """cos_geo of the local direction ``local`` (signed: > 0 on the side si.n points to)."""
    return dr.dot(si.n, si.to_world(local))


def side_of(si):
    """0 where si.wi is on the side the geometric normal points to, else 1."""
    return dr.select(geometric_cosine(si, si.wi) < 0, 1, 0)


def arrival_factor(si):
    """|cos_sh(wi)| / |cos_geo(wi)| of a particle arriving from si.wi; 0 where the shading
    and geometric sides of wi differ."""
    cos_geo, cos_sh = geometric_cosine(si, si.wi), mi.Frame3f.cos_theta(si.wi)
    same = cos_geo * cos_sh > 0
    return dr.select(same, dr.abs(cos_sh) / dr.select(same, dr.abs(cos_geo), 1.0), 0.0)


def reflectance_toward(bsdf, si, active):
    """f(si.wi, n) (Color3f) at purely diffuse hits ``si`` seen from si.wi: what multiplies
    the stored irradiance of the side of si.wi (0 where the sides of si.wi differ)."""
    cos_sh = mi.Frame3f.cos_theta(si.wi)
    ok = mi.Bool(active) & (cos_sh * geometric_cosine(si, si.wi) > 0)
    wo = mi.Vector3f(0.0, 0.0, dr.select(cos_sh < 0, -1.0, 1.0))
    return dr.select(ok, mi.Color3f(bsdf.eval(mi.BSDFContext(), si, wo, ok)), 0.0)


def patch_side(table, si):
    """2 x patch + side of hits ``si``: side 0 is the one the geometric normal points to."""
    return table.patch(si) * 2 + side_of(si)
