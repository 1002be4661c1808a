"""Transport of ``ray_bundle``: the chains' patch radiances, the global line bundles that
exchange them, and the reflection into the next global direction.

Layout: patch ``t`` of chain ``b`` is slot ``b * count + t``; with ``sides`` global
directions per iteration (+d, and -d when the bundles are used both ways) every
per-patch array holds ``sides`` blocks of slots: side 0 is the radiance leaving along
+d (or arriving along +d, for the incoming power), side 1 along -d.
"""
import warnings
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import seeds
from mi_plugins.integrators.core import SPLAT_MODE
from mi_plugins.integrators.ray_bundle.direct import SharedDirect, direct_light_mis

#: a line continues past a hit from a point this far (relative to 1 + the largest
#: coordinate) beyond the surface; Mitsuba's spawn_ray offsets ~90x more, which skips
#: surfaces closer than that behind the hit (a lamp 0.1 mm under the ceiling in metres)
LINE_EPSILON = 1e-6
#: a hit of the primitive just left, closer than this (same scale), is a re-hit of it
REHIT = 1e-4


#: peak memory of a render per lane (chain x patch side) above the scene's own, measured with
#: the defaults (first_shot, average_diffuse): 9.08 M lanes (70 k triangles, 64 chains)
#: 0.81 GB = 93 B, 32.2 M lanes (1 M triangles, 16 chains) 3.57 GB = 116 B
BYTES_PER_LANE = 120


def available_memory():
    """Bytes of memory available (Linux' MemAvailable), or None where it is not known."""
    try:
        with open("/proc/meminfo") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    except (OSError, StopIteration, ValueError):
        return None


def chains_that_fit(available, sides, patches):
    """How many chains of ``patches`` patches on ``sides`` sides fit ``available`` bytes."""
    return int(available // (BYTES_PER_LANE * sides * patches))


class ChainLayout:
    """Lanes of ``chains`` chains of ``table``'s patches, on ``sides`` sides."""

    def __init__(self, table, chains, sides):
        self.table, self.chains, self.sides, self.count = table, int(chains), int(sides), table.count
        self.slots = self.chains * self.count
        self.lanes = self.sides * self.slots

    @staticmethod
    def default_chains(chains, table, sides, available):
        """``chains``, or fewer (at least 1) where they would need over a quarter of
        ``available`` bytes (None: not known, ``chains``)."""
        if available is None:
            return int(chains)
        return max(1, min(int(chains), chains_that_fit(available / 4, sides, table.count)))

    def check_memory(self, available):
        """Refuse a layout whose iterations would need more than ``available`` bytes
        (None: not known, no check), naming the chains that would fit; warn above a quarter."""
        need = self.lanes * BYTES_PER_LANE
        if available is None or need <= available / 4:
            return
        fit = chains_that_fit(available, self.sides, self.count)
        refuse = need > available
        text = ("ray_bundle: chains=%d x %d patch sides (%d patches) = %.3g M lanes need about %.1f GB per "
                "iteration, %s the %.1f GB available" % (self.chains, self.sides * self.count, self.count,
                                                         self.lanes / 1e6, need / 1e9,
                                                         "more than" if refuse else "over a quarter of",
                                                         available / 1e9))
        if refuse:
            raise MemoryError(text + "; valid range here: chains <= %d (or a larger patch_size, subdivide=false)"
                              % fit)
        warnings.warn(text, RuntimeWarning, stacklevel=4)

    def lane_parts(self):
        """(side, triangle, chain) of every lane."""
        lane = dr.arange(mi.UInt32, self.lanes)
        slot = lane % self.slots
        return lane // self.slots, slot % self.count, slot // self.count

    def slot_of(self, tri, chain, side=0):
        return (side * self.chains + chain) * self.count + tri


@dataclass
class IterationState:
    """What one iteration hands to the next: the chains' directions ``dirs`` (one
    Vector3f per chain), the radiance ``L`` every patch sends along each side, and its
    part ``R`` carried by the bundles (L minus the source term)."""
    dirs: mi.Vector3f
    L: mi.Color3f
    R: mi.Color3f


def bounding_sphere(scene, table):
    """Centre (the bounding box's) and radius (farthest patch point, slightly enlarged) of
    a sphere around all patches."""
    center = np.array(scene.bbox().center(), dtype=np.float64)
    radius = float(np.sqrt(np.max(np.sum((table.points_np - center) ** 2, axis=-1))))
    return mi.ScalarPoint3f(*center), radius * 1.001 + 1e-6


def on_side(v, sign):
    """Local direction ``v`` mirrored in the tangent plane into the hemisphere of ``sign``
    (+: the surface normal's, -: the back).

    A patch has one radiance per direction and side, used only by the lines that meet
    the patch where its side faces them. On a flat patch every point faces the same
    way; a cell of a curved analytic shape (sphere, cylinder) can straddle the terminator
    of a direction, and its uniformly random point may face away from a direction the
    rest of the cell receives from or sends into. Evaluated there as it stands, the
    emission and the BSDF are zero and the cell's whole value is lost: in the furnace
    inside the analytic sphere -1.6 % at the quick patch size (0.43), ~h^2. So the
    directions are taken to the patch's side at the random point: the patch average
    the lines need, unchanged on flat patches wherever their value is used."""
    return mi.Vector3f(v.x, v.y, dr.mulsign(dr.abs(v.z), sign))


def bsdf_over_cosine(si, incoming, towards_source):
    """f(towards_source -> si.wi) * incoming, with f = bsdf.eval / |cos|, for sources on
    the side of ``si.wi`` (the back side of two-sided BSDFs included; the source
    direction is taken to that side, see :func:`on_side`)."""
    bsdf = si.bsdf()
    wo = on_side(si.to_local(towards_source), mi.Frame3f.cos_theta(si.wi))
    cos_in = dr.abs(mi.Frame3f.cos_theta(wo))
    value = mi.Color3f(bsdf.eval(mi.BSDFContext(), si, wo, cos_in > 1e-6))
    return dr.select(cos_in > 1e-6, value / cos_in, 0.0) * incoming


class Transport:
    """The transfer and reflection steps of all chains of one render."""

    def __init__(self, scene, layout, resolution, first_shot, seed):
        self.scene, self.layout, self.resolution, self.first_shot = scene, layout, int(resolution), first_shot
        self.center, self.radius = bounding_sphere(scene, layout.table)
        self.lines = self.resolution ** 2 * layout.chains
        self.rng_lines = seeds.pcg(self.lines, seed, "lines")
        self.rng_patch = seeds.pcg(layout.lanes, seed, "patches")
        self.weight = 4.0 * np.pi / layout.sides      # solid angle per global direction
        # the environment emitter, a source the bundles carry (with first_shot it is
        # direct light, estimated by next-event estimation instead)
        self.environment = None if first_shot else scene.environment()
        # with first_shot, the direct light of purely diffuse patches, shared by the chains
        self.direct = SharedDirect(scene, layout.table, seed) if first_shot else None

    def state(self):
        return self.rng_lines.state, self.rng_patch.state, self.direct.state() if self.direct is not None else None

    def source(self, si, tri):
        """The radiance a patch point of patch ``tri`` sends toward ``si.wi`` without the
        bundles' transport: its emission, or with ``first_shot`` the direct light it
        reflects: the shared running mean of purely diffuse patches (updated here, once
        per iteration), else one light and one BSDF sample of the lane (no rays where
        ``si.wi`` is behind a surface that neither transmits nor has a back side)."""
        if not self.first_shot:
            return mi.Color3f(si.emitter(self.scene).eval(si))
        direct = self.direct
        direct.update()
        if direct.covers_all:
            return direct.mean(tri)
        bsdf = si.bsdf()
        flags = bsdf.flags()
        can_reach = ((mi.Frame3f.cos_theta(si.wi) > 0) | mi.has_flag(flags, mi.BSDFFlags.BackSide)
                     | mi.has_flag(flags, mi.BSDFFlags.Transmission))
        if not direct.any:
            return direct_light_mis(self.scene, si, bsdf, self.rng_patch, can_reach)
        shared = direct.is_shared(tri)
        own = direct_light_mis(self.scene, si, bsdf, self.rng_patch, can_reach & ~shared)
        return dr.select(shared, direct.mean(tri), own)

    def _patch_points(self, dirs):
        """A uniformly random point of every patch on every lane, seen from the lane's
        side of its chain's direction; returns (si, triangle, chain)."""
        side, tri, chain = self.layout.lane_parts()
        out = dr.gather(mi.Vector3f, dirs, chain) * (1.0 - 2.0 * mi.Float(side))
        sample = mi.Point2f(self.rng_patch.next_float32(), self.rng_patch.next_float32())
        table = self.layout.table
        si = table.surface_interaction(tri, sample, out)
        si.wi = on_side(si.wi, dr.select(tri < table.front_count, 1.0, -1.0))   # the patch's side (on_side)
        return si, tri, chain

    def initial(self, dirs):
        """L_0 = the source term along every side of ``dirs`` (nothing carried yet)."""
        si, tri, _ = self._patch_points(dirs)
        return IterationState(dirs, self.source(si, tri), dr.zeros(mi.Color3f, self.layout.lanes))

    def transfer(self, state):
        """Walk every chain's bundle of parallel lines along its direction d (jittered
        every iteration; all successive hits of each line) and return the incoming power
        per unit projected area of every patch, summed over the lines, for every side:
        side 0 arriving along +d (sent by the previous hit facing +d), side 1 along -d."""
        layout, table, res = self.layout, self.layout.table, self.resolution
        per_chain = res * res
        k = dr.arange(mi.UInt32, self.lines)
        chain, line = k // per_chain, k % per_chain
        d = dr.gather(mi.Vector3f, state.dirs, chain)
        frame = mi.Frame3f(d)
        cell = 2.0 * self.radius / res
        u = (mi.Float(line % res) + self.rng_lines.next_float32()) * cell - self.radius
        v = (mi.Float(line // res) + self.rng_lines.next_float32()) * cell - self.radius
        ray = mi.Ray3f(self.center + frame.s * u + frame.t * v - d * (1.01 * self.radius), d)
        incoming = dr.zeros(mi.Color3f, layout.lanes)
        back = layout.sides - 1          # the side whose radiance travels along -d
        L, scene, area = state.L, self.scene, cell * cell
        sky_ahead, sky_behind = self.sky(d)

        def body(ray, active, prev, prev_fwd, first, last_shape, last_prim):
            pi = scene.ray_intersect_preliminary(ray, active)
            found = active & pi.is_valid()
            si = pi.compute_surface_interaction(ray, mi.RayFlags.Minimal | mi.RayFlags.UV, found)   # uv: patches of analytic shapes
            shape = dr.reinterpret_array(mi.UInt32, pi.shape)
            scale = 1.0 + dr.max(dr.abs(si.p))
            # the primitive just left, found again right behind the start: not a new surface
            hit = found & ~((shape == last_shape) & (pi.prim_index == last_prim) & (pi.t < REHIT * scale))
            # the side facing the line's origin receives, the side facing ahead sends
            # (Mitsuba's orientation, flip_normals included; one-sided surfaces have one)
            receiver, receives = table.side_patch(si, -d)
            sender, sends = table.side_patch(si, d)
            slot, exchange = layout.slot_of(receiver, chain), hit & receives & prev_fwd
            dr.scatter_add(incoming, dr.gather(mi.Color3f, L, prev, exchange) * area, slot, exchange, mode=SPLAT_MODE)
            if back:
                dr.scatter_add(incoming, dr.gather(mi.Color3f, L, slot + back * layout.slots, exchange) * area,
                               prev + back * layout.slots, exchange, mode=SPLAT_MODE)
            if self.environment is not None:     # the first surface on a line sees the sky behind it
                lit = hit & first & receives
                dr.scatter_add(incoming, sky_behind * area, slot, lit, mode=SPLAT_MODE)
                if back:                         # a line leaving the scene: its last surface sees the sky
                    lit = active & ~pi.is_valid() & prev_fwd
                    dr.scatter_add(incoming, sky_ahead * area, prev + back * layout.slots, lit, mode=SPLAT_MODE)
            beyond = si.p + si.n * dr.mulsign(LINE_EPSILON * scale, dr.dot(si.n, d))
            return (mi.Ray3f(beyond, d), found, dr.select(hit, layout.slot_of(sender, chain), prev),
                    dr.select(hit, hit & sends, prev_fwd), first & ~hit, shape, mi.UInt32(pi.prim_index))

        # loop state: the line's ray, whether it is still inside the scene, the slot of
        # its previous hit, whether that hit faces +d (sends along it), no hit yet, and
        # the shape and primitive of the last surface found (to tell re-hits of it)
        start = (u * u + v * v) <= self.radius * self.radius
        none = dr.full(mi.UInt32, 0xFFFFFFFF, self.lines)
        dr.while_loop((ray, start, dr.zeros(mi.UInt32, self.lines), mi.Bool(False), mi.Bool(True), none, none),
                      lambda ray, active, *rest: active, body)
        return incoming

    def sky(self, d):
        """The environment's radiance arriving along -d (seen looking along +d) and along
        +d (seen looking along -d); zero without an environment emitter the bundles carry."""
        if self.environment is None:
            return mi.Color3f(0.0), mi.Color3f(0.0)
        look = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
        look.wi = -d                             # a miss along +d has si.wi = -d
        ahead = mi.Color3f(self.environment.eval(look))
        look.wi = d
        return ahead, mi.Color3f(self.environment.eval(look))

    def reflect(self, state, incoming, new_dirs):
        """The next iteration's radiance along every side of ``new_dirs``:
        L_new = source + R, R = weight * f * (incoming along +-d) / A_i."""
        layout = self.layout
        si, tri, chain = self._patch_points(new_dirs)
        d = dr.gather(mi.Vector3f, state.dirs, chain)
        area = dr.maximum(dr.gather(mi.Float, layout.table.area, tri), 1e-30)   # degenerate: never hit
        R = mi.Color3f(0.0)
        for j in range(layout.sides):   # radiance arriving along +d comes from -d, and back
            arriving = dr.gather(mi.Color3f, incoming, layout.slot_of(tri, chain, j))
            R += self.weight * bsdf_over_cosine(si, arriving / area, d * (2.0 * j - 1.0))
        return IterationState(new_dirs, self.source(si, tri) + R, R)
