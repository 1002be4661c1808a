"""Transport of ``ray_bundle``: the chains' patch radiances, the global line bundles that
exchange them, and the reflection into the next global direction.

Layout: patch ``t`` of chain ``b`` is slot ``b * count + t``; with ``sides`` global
directions per iteration (+d, and -d when the bundles are used both ways) every
per-patch array holds ``sides`` blocks of slots: side 0 is the radiance leaving along
+d (or arriving along +d, for the incoming power), side 1 along -d.

Orders: with an unbounded depth a chain keeps one radiance per lane, L = S + T L (S the
source term: the emission, or with ``first_shot`` the direct light reflected). With a
finite ``max_depth`` it keeps the bounce orders apart, L_0 = S and L_k = T L_{k-1}, so
that an image can take exactly the orders a path of that depth reaches
(:attr:`ChainLayout.orders` of them).
"""
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import seeds
from mi_plugins.render.frame import SPLAT_MODE
from mi_plugins.integrators.ray_bundle.direct import SharedDirect, direct_light_mis
from mi_plugins.integrators.ray_bundle.sharing import DiffuseSharing
from mi_plugins.base.queries import scene_bounds
from mi_plugins.patches.refinement import CHILDREN, child_index

#: a line continues past a hit from a point this far (relative to 1 + the largest
#: coordinate) beyond the surface; Mitsuba's spawn_ray offsets ~90x more, which skips
#: surfaces closer than that behind the hit (a lamp 0.1 mm under the ceiling in metres)
LINE_EPSILON = 1e-6
#: a hit of the primitive just left, closer than this (same scale), is a re-hit of it
REHIT = 1e-4


@dataclass
class ChainState:
    """What one iteration hands to the next: the chains' directions ``dirs`` (one
    Vector3f per chain), the radiance every patch sends along each side, per order
    (``L``, a list), its part ``R`` carried by the bundles (L minus the source term), and
    the part of R that is the environment's light reflected once (``sky``; zero without
    an environment the bundles carry): a source too for the convergence model, which
    arrives in full from the first iteration."""
    dirs: mi.Vector3f
    L: list
    R: mi.Color3f
    sky: mi.Color3f


@dataclass
class Streams:
    """The random streams of the transport: line jitter, and points on patches."""
    lines: mi.PCG32
    patches: mi.PCG32


class ChainLayout:
    """Lanes of ``chains`` chains of ``table``'s patches, on ``sides`` sides, with
    ``orders`` radiance values per lane (1: unbounded depth)."""

    def __init__(self, table, chains, sides, orders=1):
        self.table, self.chains, self.sides, self.count = table, int(chains), int(sides), table.count
        self.orders = int(orders)
        self.slots = self.chains * self.count
        self.lanes = self.sides * self.slots

    def lane_parts(self):
        """(side, triangle, chain) of every lane."""
        lane = dr.arange(mi.UInt32, self.lanes)
        slot = lane % self.slots
        return lane // self.slots, slot % self.count, slot // self.count

    def slot_of(self, tri, chain, side=0):
        return (side * self.chains + chain) * self.count + tri


def bounding_sphere(scene, table):
    """Centre (of the box around all shapes) and radius (farthest patch point, slightly
    enlarged) of a sphere around all patches; kept with the table (``MeshTable.derived``),
    whose geometry sets it."""
    def make():
        lo, hi = scene_bounds(scene)
        center = 0.5 * (lo + hi)
        radius = float(np.sqrt(np.max(np.sum((table.points_np - center) ** 2, axis=-1))))
        return mi.ScalarPoint3f(*center), radius * 1.001 + 1e-6
    return table.derived("bounding sphere", make)


def on_side(v, n, sign):
    """World direction ``v`` mirrored in the tangent plane of the geometric normal ``n``
    into the hemisphere of ``sign`` (+: the normal's, -: the back).

    A patch has one radiance per direction and side, used only by the lines that meet
    the patch where its side faces them. On a flat patch every point faces the same
    way; a cell of a curved analytic shape (sphere, cylinder) can straddle the terminator
    of a direction, and its uniformly random point may face away from a direction the
    rest of the cell receives from or sends into. Evaluated there as it stands, the
    emission and the BSDF are zero and the cell's whole value is lost: in the furnace
    inside the analytic sphere -1.6 % at the quick patch size (0.43), ~h^2. So the
    directions are taken to the patch's side at the random point: the patch average
    the lines need, unchanged on flat patches wherever their value is used."""
    c = dr.dot(v, n)
    return dr.select(c * sign < 0, v - 2.0 * c * n, v)


def bsdf_over_cosine(si, bsdf, towards_source, active=True):
    """f(towards_source -> si.wi) / |cos_geo|: the BSDF value (Mitsuba's, with its shading
    cosine) per unit of power arriving per unit area from ``towards_source`` (world),
    which carries the *geometric* cosine |n . w| (a line bundle's projected area): what
    a path tracer integrates over solid angle. Sources on the side of ``si.wi`` (the
    back side of two-sided BSDFs included; the direction is taken to that side, see
    :func:`on_side`)."""
    side = dr.sign(dr.dot(si.n, si.to_world(si.wi)))
    w = on_side(towards_source, si.n, side)
    cos_geo = dr.abs(dr.dot(si.n, w))
    ok = mi.Bool(active) & (cos_geo > 1e-6)
    value = mi.Color3f(bsdf.eval(mi.BSDFContext(), si, si.to_local(w), ok))
    return dr.select(ok, value / dr.select(ok, cos_geo, 1.0), 0.0)


@dataclass
class ChildSums:
    sums: mi.Float        # luminance arriving per (front patch, side, child)
    squares: mi.Float     # the sum of the squares of what each line brought there


class ChildStats:
    """What the lines bring to each child of each front patch side (``mi_plugins.patches.refinement``)."""

    def __init__(self, table):
        self.table = table
        size = table.front_count * 2 * CHILDREN
        self.state = ChildSums(dr.zeros(mi.Float, size), dr.zeros(mi.Float, size))
        dr.make_opaque(self.state.sums, self.state.squares)

    def index(self, located, si, toward, active):
        """The bin of the child holding the hit ``located`` on the side facing ``toward``."""
        side = dr.select(dr.dot(si.n, toward) > 0, 0, 1)
        return (located[0] * 2 + side) * CHILDREN + child_index(self.table, located, active)

    def add(self, located, si, toward, value, active):
        self.add_at(self.index(located, si, toward, active), value, active)

    def add_at(self, index, value, active):
        brought = mi.luminance(value)
        dr.scatter_add(self.state.sums, brought, index, active, mode=SPLAT_MODE)
        dr.scatter_add(self.state.squares, brought * brought, index, active, mode=SPLAT_MODE)

    def numpy(self):
        """(sums, squares), numpy (K, 2, 8) each."""
        shape = (self.table.front_count, 2, CHILDREN)
        return (np.array(self.state.sums, dtype=np.float64).reshape(shape),
                np.array(self.state.squares, dtype=np.float64).reshape(shape))


class Transport:
    """The transfer and reflection steps of all chains of one render. ``finite``: the
    orders are bounce orders (a finite depth), else one unbounded value per lane."""

    def __init__(self, scene, layout, resolution, first_shot, seed, finite=False, point_sources=True, children=False,
                 share_diffuse=False):
        self.scene, self.layout, self.resolution, self.first_shot = scene, layout, int(resolution), first_shot
        #: with ``share_diffuse`` (and several chains) purely diffuse patch sides reflect
        #: the mean of all chains (:class:`DiffuseSharing`)
        self.sharing = DiffuseSharing(layout) if share_diffuse and layout.chains > 1 else None
        #: with ``children``: what arrives in each child of each front patch side (refinement)
        self.children = ChildStats(layout.table) if children else None
        self.finite, self.point_sources = bool(finite), bool(point_sources)
        self.center, self.radius = bounding_sphere(scene, layout.table)
        self.lines = self.resolution ** 2 * layout.chains
        self.streams = Streams(seeds.pcg(self.lines, seed, "lines"), seeds.pcg(layout.lanes, seed, "patches"))
        self.weight = 4.0 * np.pi / layout.sides      # solid angle per global direction
        # the environment emitter, a source the bundles carry (with first_shot it is
        # direct light, estimated by next-event estimation instead)
        self.environment = None if first_shot else scene.environment()
        # with first_shot, the direct light of purely diffuse patches, shared by the chains
        self.direct = SharedDirect(scene, layout.table, seed) if first_shot else None

    def mutable(self):
        """The state the iterations change (random streams, shared direct light, children)."""
        return (self.streams, self.direct.state if self.direct is not None else None,
                self.children.state if self.children is not None else None)

    def source(self, si, tri):
        """The radiance a patch point of patch ``tri`` sends toward ``si.wi`` without the
        bundles' transport: its emission, or with ``first_shot`` the direct light it
        reflects: the shared running mean of purely diffuse patches (updated here, once
        per iteration), else the lane's own next-event estimate (no rays where
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
        rng = self.streams.patches
        if not direct.any:
            return direct_light_mis(self.scene, si, bsdf, rng, can_reach)
        shared = direct.is_shared(tri)
        own = direct_light_mis(self.scene, si, bsdf, rng, can_reach & ~shared)
        return dr.select(shared, direct.mean(tri), own)

    def _patch_points(self, dirs):
        """A uniformly random point of every patch on every lane, seen from the lane's
        side of its chain's direction; returns (si, triangle, chain)."""
        side, tri, chain = self.layout.lane_parts()
        out = dr.gather(mi.Vector3f, dirs, chain) * (1.0 - 2.0 * mi.Float(side))
        rng = self.streams.patches
        sample = mi.Point2f(rng.next_float32(), rng.next_float32())
        table = self.layout.table
        si = table.surface_interaction(tri, sample)
        si.wi = si.to_local(on_side(out, si.n, dr.select(tri < table.front_count, 1.0, -1.0)))   # the patch's side
        return si, tri, chain

    def initial(self, dirs):
        """L_0 = the source term along every side of ``dirs`` (nothing carried yet)."""
        si, tri, _ = self._patch_points(dirs)
        zero = lambda: dr.zeros(mi.Color3f, self.layout.lanes)
        L = [self.source(si, tri)] + [zero() for _ in range(self.layout.orders - 1)]
        return ChainState(dirs, L, zero(), zero() if self.environment is not None else mi.Color3f(0.0))

    def transfer(self, state):
        """Walk every chain's bundle of parallel lines along its direction d (jittered
        every iteration; all successive hits of each line) and return the incoming power
        per unit projected area of every patch, summed over the lines, for every side
        and order: side 0 arriving along +d (sent by the previous hit facing +d), side 1
        along -d; and its part that comes from the environment (``ChainState.sky``)."""
        layout, table, res = self.layout, self.layout.table, self.resolution
        per_chain = res * res
        k = dr.arange(mi.UInt32, self.lines)
        chain, line = k // per_chain, k % per_chain
        d = dr.gather(mi.Vector3f, state.dirs, chain)
        frame = mi.Frame3f(d)
        cell = 2.0 * self.radius / res
        rng = self.streams.lines
        u = (mi.Float(line % res) + rng.next_float32()) * cell - self.radius
        v = (mi.Float(line // res) + rng.next_float32()) * cell - self.radius
        ray = mi.Ray3f(self.center + frame.s * u + frame.t * v - d * (1.01 * self.radius), d)
        incoming = [dr.zeros(mi.Color3f, layout.lanes) for _ in state.L]
        from_sky = dr.zeros(mi.Color3f, layout.lanes if self.environment is not None else 1)
        stats = self.children
        back = (layout.sides - 1) * layout.slots     # offset of the side whose radiance travels along -d
        scene, area = self.scene, cell * cell
        sky_ahead, sky_behind = self.sky(d)

        def body(ray, active, prev, prev_fwd, prev_src, prev_child, first, last_shape, last_prim, rng):
            pi = scene.ray_intersect_preliminary(ray, active)
            found = active & pi.is_valid()
            si = pi.compute_surface_interaction(ray, mi.RayFlags.All, found)
            shape = dr.reinterpret_array(mi.UInt32, pi.shape)
            scale = 1.0 + dr.max(dr.abs(si.p))
            # the primitive just left, found again right behind the start: not a new surface
            hit = found & ~((shape == last_shape) & (pi.prim_index == last_prim) & (pi.t < REHIT * scale))
            # the side facing the line's origin receives, the side facing ahead sends
            # (Mitsuba's orientation, flip_normals included; one-sided surfaces have one)
            located = table.locate(si, found)
            receiver, receives = table.side_of(located[0], si, -d)
            sender, sends = table.side_of(located[0], si, d)
            slot, exchange = layout.slot_of(receiver, chain), hit & receives & prev_fwd
            arriving = self.carried(state, prev, prev_src, exchange)
            for inc, value in zip(incoming, arriving):
                dr.scatter_add(inc, value * area, slot, exchange, mode=SPLAT_MODE)
            if stats is not None:      # where in the receiving patch it arrives
                stats.add(located, si, -d, sum(arriving[1:], arriving[0]) * area, exchange)
            if back:                   # the receiving side sends back along -d (si.wi is -d)
                own = self.point_source(si, exchange, rng) if self.point_sources else None
                for inc, value in zip(incoming, self.carried(state, slot + back, own, exchange)):
                    dr.scatter_add(inc, value * area, prev + back, exchange, mode=SPLAT_MODE)
            if self.environment is not None:     # the first surface on a line sees the sky behind it
                lit = hit & first & receives
                for target in (incoming[0], from_sky):
                    dr.scatter_add(target, sky_behind * area, slot, lit, mode=SPLAT_MODE)
                if stats is not None:
                    stats.add(located, si, -d, sky_behind * area, lit)
                if back:                         # a line leaving the scene: its last surface sees the sky
                    lit = active & ~pi.is_valid() & prev_fwd
                    for target in (incoming[0], from_sky):
                        dr.scatter_add(target, sky_ahead * area, prev + back, lit, mode=SPLAT_MODE)
                    if stats is not None:
                        stats.add_at(prev_child, sky_ahead * area, lit)
            ahead = mi.SurfaceInteraction3f(si)
            ahead.wi = si.to_local(d)
            src = (dr.select(hit & sends, self.point_source(ahead, hit & sends, rng), prev_src)
                   if self.point_sources else prev_src)
            beyond = si.p + si.n * dr.mulsign(LINE_EPSILON * scale, dr.dot(si.n, d))
            child = (dr.select(hit, stats.index(located, si, d, hit), prev_child)
                     if stats is not None and self.environment is not None else prev_child)
            return (mi.Ray3f(beyond, d), found, dr.select(hit, layout.slot_of(sender, chain), prev),
                    dr.select(hit, hit & sends, prev_fwd), src, child, first & ~hit, shape,
                    mi.UInt32(pi.prim_index), rng)

        # loop state: the line's ray, whether it is still inside the scene, the slot of
        # its previous hit, whether that hit faces +d (sends along it), the source
        # radiance it sends and its child's bin (refinement: where the sky ahead arrives),
        # no hit yet, the shape and primitive of the last surface found (to tell re-hits
        # of it), and the line's random stream (the source terms)
        start = (u * u + v * v) <= self.radius * self.radius
        none = dr.full(mi.UInt32, 0xFFFFFFFF, self.lines)
        out = dr.while_loop((ray, start, dr.zeros(mi.UInt32, self.lines), mi.Bool(False),
                             dr.zeros(mi.Color3f, self.lines), dr.zeros(mi.UInt32, self.lines), mi.Bool(True),
                             none, none, rng),
                            lambda ray, active, *rest: active, body)
        self.streams.lines = out[-1]
        return incoming, from_sky

    def point_source(self, si, active, rng):
        """The source term the surface point ``si`` sends toward ``si.wi`` (world
        interaction of a hit): its emission, or with ``first_shot`` the direct light it
        reflects (``direct.direct_light_mis``). Evaluated where the radiance
        leaves, not averaged over the patch: the direct light can change by orders of
        magnitude within a patch (a lamp 1 cm under a ceiling, a spot's cone on a large
        plane), and a line leaving the dark part of a patch must not carry the bright
        part's light (+92 % in the first case, -4 % in the second). ``point_sources=false``
        keeps the patch's running mean instead: less noise, exact where the whole radiance
        is constant per patch (the analytic constant-radiance scenes)."""
        if not self.first_shot:
            return dr.select(active, mi.Color3f(si.emitter(self.scene, active).eval(si, active)), 0.0)
        return direct_light_mis(self.scene, si, si.bsdf(), rng, active)

    def carried(self, state, slot, src, active):
        """The radiance a patch side sends, per order: the bundles' part (R, or the orders
        k >= 1) from the patch's values at ``slot``, the source part ``src`` evaluated at
        the point (order 0); without ``point_sources`` the patch's values alone (the
        source part its running mean over the patch)."""
        if not self.point_sources:
            return [dr.gather(mi.Color3f, L, slot, active) for L in state.L]
        if not self.finite:
            return [dr.gather(mi.Color3f, state.R, slot, active) + src]
        return [src] + [dr.gather(mi.Color3f, L, slot, active) for L in state.L[1:]]

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

    def reflect(self, state, incoming, new_dirs, from_sky):
        """The next iteration's radiance along every side of ``new_dirs``: the source S
        plus the reflection R = weight * f * (incoming along +-d) / A_i (unbounded), or
        the orders S, T(incoming_0), ..., T(incoming_{K-2}) (finite depth)."""
        layout = self.layout
        si, tri, chain = self._patch_points(new_dirs)
        d = dr.gather(mi.Vector3f, state.dirs, chain)
        area = dr.maximum(dr.gather(mi.Float, layout.table.area, tri), 1e-30)   # degenerate: never hit
        bsdf = si.bsdf()
        # radiance arriving along +d comes from -d, and back: one BSDF value per side
        f = [self.weight * bsdf_over_cosine(si, bsdf, d * (2.0 * j - 1.0)) / area for j in range(layout.sides)]

        def reflected(inc):
            return sum((f[j] * dr.gather(mi.Color3f, inc, layout.slot_of(tri, chain, j))
                        for j in range(layout.sides)), mi.Color3f(0.0))
        S = self.source(si, tri)
        parts = [reflected(inc) for inc in (incoming[:-1] if self.finite else incoming[:1])]
        sky = reflected(from_sky) if self.environment is not None else None   # (none: no memory)
        if self.sharing is not None:
            dr.schedule(S)          # (evaluated with the shared sums: one kernel traces the patch points)
            parts, sky = self.sharing.share(parts, sky, tri)
        sky = mi.Color3f(0.0) if sky is None else sky
        if not self.finite:
            return ChainState(new_dirs, [S + parts[0]], parts[0], sky)
        return ChainState(new_dirs, [S] + parts, sum(parts, mi.Color3f(0.0)), sky)
