"""Camera samples of the package's integrators, and camera paths through specular chains.

:class:`CameraPass`: one pass of camera samples drawn from the sensor's sampler (film
position, aperture, time), the way Mitsuba's own integrators draw them.
:func:`specular_chain`: follows camera rays through surfaces whose BSDF is purely
delta (mirrors, glass) to the first surface with a non-delta component, where the
integrators evaluate their own estimate, collecting the emission seen on the way.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import queries

#: camera paths through specular chains play Russian roulette after this many bounces
#: (survival probability min(max throughput, 0.95), so perfect mirrors terminate too)
RR_DEPTH = 5
#: "no limit" of the chains' depth counters
UNBOUNDED = 1 << 30


def grid(film):
    """(crop size, border, grid size) of a film's camera samples: the crop window plus
    the reconstruction filter's border where the film samples it."""
    size = film.crop_size()
    border = film.rfilter().border_size() if film.sample_border() else 0
    return size, border, size + 2 * border


def grid_position(idx, full, border):
    """The pixel (Vector2i, crop window coordinates: the border's pixels below 0) of the
    grid pixels ``idx`` (row by row; :func:`grid`)."""
    py = idx // full[0]
    px = idx - py * full[0]
    return mi.Vector2i(mi.Int32(px) - border, mi.Int32(py) - border)


def film_ray(sensor, pos_f, time, aperture, active=True):
    """(ray, weight) of ``sensor`` through film position ``pos_f`` (crop offset included),
    mapped as Mitsuba's own integrators map it. The differential variant: 'irradiancemeter'
    and 'batch' implement only that one (Mitsuba 3.9.1: their sample_ray raises "not
    implemented"), as Mitsuba's path calls."""
    film = sensor.film()
    scale = dr.rcp(mi.ScalarVector2f(film.crop_size()))
    uv = dr.fma(pos_f, scale, -mi.ScalarVector2f(film.crop_offset()) * scale)
    return sensor.sample_ray_differential(time, 0.0, uv, aperture, active)


def emission_edges(frame, shifts):
    """numpy bool (grid pixels, row by row; :func:`grid`): the pixels whose camera rays
    through ``shifts`` (positions in the pixel) do not all see the same emission at their
    first hit (a lamp's or the sky's edge crosses them; a pixel inside a uniform emitter
    or seeing none is left out), and their neighbours (a lamp narrower than the shifts'
    spacing, the filter's reach); None for a sensor whose rays ignore the film position.
    One kernel per shift over the pixels (the shift an opaque value: one compilation), the
    running lowest and highest emission per pixel kept: memory of a few pixel-sized arrays."""
    film, sensor = frame.film, frame.sensor
    _, border, full = grid(film)
    pixels = int(full[0]) * int(full[1])
    corner = mi.Vector2f(grid_position(dr.arange(mi.UInt32, pixels), full, border) + mi.Vector2i(film.crop_offset()))
    low, high = dr.full(mi.Color3f, dr.inf, pixels), dr.full(mi.Color3f, -dr.inf, pixels)
    for x, y in shifts:                # a few shifts: a kernel each, the same one
        pos_f = corner + mi.Vector2f(dr.opaque(mi.Float, x), dr.opaque(mi.Float, y))
        ray, _ = film_ray(sensor, pos_f, sensor.shutter_open(), mi.Point2f(0.5))
        if dr.width(ray.o) != pixels or dr.width(ray.d) != pixels:
            return None                 # a sensor whose rays ignore the film position
        seen = seen_emission(frame.scene, mi.Ray3f(ray.o, ray.d, ray.maxt, ray.time, ray.wavelengths))
        low, high = dr.minimum(low, seen), dr.maximum(high, seen)
        dr.eval(low, high)
    peak = dr.maximum(dr.max(dr.abs(low)), dr.max(dr.abs(high)))
    edge = np.array(dr.max(high - low) > 1e-3 * peak, dtype=bool).reshape(int(full[1]), int(full[0]))
    grown = edge.copy()
    grown[1:] |= edge[:-1]
    grown[:-1] |= edge[1:]
    wide = grown.copy()
    wide[:, 1:] |= grown[:, :-1]
    wide[:, :-1] |= grown[:, 1:]
    return wide.ravel()


class CameraPass:
    """One pass of camera samples: ``per_pixel`` samples of every pixel, drawn from
    ``sampler`` (a seeded clone of the sensor's sampler). ``ray``, ``weight`` (the
    sensor's importance weight), ``pos`` (film position to splat at), ``pixel`` (flat
    index of the sample's pixel in the crop window), ``sampler`` (draw further numbers
    from it), ``independent`` (it is Mitsuba's independent sampler, which stratifies
    nothing), ``count`` (lanes: ``per_pixel`` consecutive lanes per pixel of the
    ``grid_width`` x ``grid_height`` grid, the crop window plus the filter's border when
    the film samples it), ``grid_pixel`` (the lane's pixel in that grid), ``box`` (a box
    filter: ``pos`` is the pixel), ``film_rays`` (the sensor's rays follow the film
    position: :func:`lattice_rays` can draw further rays through a pixel), ``sensor``."""

    def __init__(self, frame, sampler, per_pixel):
        film, sensor = frame.film, frame.sensor
        size, border, full = grid(film)
        idx = dr.arange(mi.UInt32, dr.prod(full) * per_pixel) // dr.opaque(mi.UInt32, per_pixel)
        pos = grid_position(idx, full, border)
        self.pixel = mi.UInt32(dr.clip(pos.y, 0, size[1] - 1) * size[0] + dr.clip(pos.x, 0, size[0] - 1))
        pos += mi.Vector2i(film.crop_offset())
        pos_f = mi.Vector2f(pos) + sampler.next_2d()
        aperture = sampler.next_2d() if sensor.needs_aperture_sample() else mi.Point2f(0.5)
        time = sensor.shutter_open()
        if sensor.shutter_open_time() > 0:
            time += sampler.next_1d() * sensor.shutter_open_time()
        ray, weight = film_ray(sensor, pos_f, time, aperture)
        count = dr.width(idx)
        self.film_rays = dr.width(ray.o) == count and dr.width(ray.d) == count
        if dr.width(ray.o) != count or dr.width(ray.d) != count or dr.width(weight) != count:
            # a sensor whose rays ignore the film sample (radiancemeter: one fixed ray) gives
            # one lane: widened, so that every camera sample draws its own numbers downstream
            grow = dr.zeros(mi.Float, count)
            ray = mi.Ray3f(ray.o + grow, ray.d + grow, ray.maxt + grow, ray.time + grow, ray.wavelengths)
            weight = mi.Color3f(weight) + grow
        self.ray = mi.Ray3f(ray.o, ray.d, ray.maxt, ray.time, ray.wavelengths)
        self.weight = mi.Color3f(weight)
        # box filter: splat at the pixel itself (as Mitsuba's ADIntegrator does)
        self.box = film.rfilter().is_box_filter()
        self.pos = mi.Vector2f(pos) if self.box else pos_f
        self.sensor = sensor
        self.sampler = sampler
        self.independent = queries.plugin_name(sampler) in ("independent", "IndependentSampler")
        self.count = count
        self.per_pixel = int(per_pixel)
        self.grid_pixel = idx            # the lane's pixel in the grid (with border), row by row
        self.grid_width, self.grid_height = int(full[0]), int(full[1])   # pixels of the lanes (with border)


def lattice_rays(sensor, pixels, per_pixel, shifts, state):
    """Further camera rays through the grid pixels ``pixels`` (UInt32, :func:`grid`):
    ``per_pixel`` lanes per pixel, each a uniform position in the pixel (and its own
    aperture point and time) shifted by every point of ``shifts`` modulo the pixel, so that
    a lane's rays stratify its pixel. Yields (ray, weight, film position, pixel corner)
    per shift; ``state``: the seed (UInt64) of the lanes' PCG32 streams (sequences from
    2^32 on, apart from those of the camera paths, whose lanes number below 2^32)."""
    film = sensor.film()
    _, border, full = grid(film)
    lane = dr.arange(mi.UInt32, dr.width(pixels) * int(per_pixel))
    rng = mi.PCG32(dr.width(lane), initstate=state, initseq=mi.UInt64(lane) + (1 << 32))
    pixel = dr.gather(mi.UInt32, pixels, lane // int(per_pixel))
    corner = mi.Vector2f(grid_position(pixel, full, border) + mi.Vector2i(film.crop_offset()))
    offset = mi.Vector2f(rng.next_float32(), rng.next_float32())
    aperture = mi.Point2f(rng.next_float32(), rng.next_float32()) if sensor.needs_aperture_sample() \
        else mi.Point2f(0.5)
    time = sensor.shutter_open() + (rng.next_float32() * sensor.shutter_open_time()
                                    if sensor.shutter_open_time() > 0 else 0.0)
    for shift in shifts:
        inside = offset + mi.ScalarVector2f(shift)
        pos_f = corner + inside - dr.floor(inside)
        ray, weight = film_ray(sensor, pos_f, time, aperture)
        yield mi.Ray3f(ray.o, ray.d, ray.maxt, ray.time, ray.wavelengths), mi.Color3f(weight), pos_f, corner


class SpecularChain:
    """Result of :func:`specular_chain`: ``ray`` reaching the first surface with a
    non-delta component (``reached``), its ``throughput``, the ``emission`` seen along the
    chain (including that surface's own; ``first``: its part seen by the first segment),
    ``depth``, the specular bounces before it, ``surface``: the first segment met a
    surface that is not hidden (the film's alpha), and ``si``: the surface interaction at
    ``ray``'s hit where it is known (a scene without surfaces to follow), else None."""


def specular_chain(scene, ray, rng, max_depth=-1, max_bounces=None, hide_emitters=False):
    """Follow camera rays (one per lane) through purely specular surfaces.

    Delta BSDFs are sampled with ``rng`` (a per-lane ``mi.PCG32``); the path stops at the
    first surface with any non-delta component (the delta lobes of mixed BSDFs such as
    ``plastic`` are not followed), after ``max_bounces`` specular bounces (None or -1:
    no limit), or when Mitsuba's ``max_depth`` (1: emission seen directly only) is
    reached; Russian roulette after ``RR_DEPTH`` bounces. Rays that leave the scene see
    the environment emitter, if any. ``hide_emitters`` as Mitsuba means it: the first
    segment passes through area emitters (Mitsuba's ``path`` shows what lies behind a
    hidden emitter) and does not see the environment."""
    ctx = mi.BSDFContext()
    depth_limit = mi.UInt32(max_depth if max_depth >= 0 else UNBOUNDED)
    unbounded = max_bounces is None or max_bounces < 0
    bounce_limit = mi.UInt32(UNBOUNDED if unbounded else max_bounces)

    def body(ray, throughput, emission, first, active, reached, surface, depth, rng):
        si = scene.ray_intersect(ray, active)
        emitter = si.emitter(scene, active)
        hidden = active & si.is_valid() & (depth == 0) & (emitter != None) if hide_emitters else mi.Bool(False)  # noqa
        on = active & ~hidden
        seen = on & (depth < depth_limit)      # hits, and misses that see the environment
        show = seen & si.is_valid()
        surface |= show & (depth == 0)
        visible = seen & (depth > 0) if hide_emitters else seen
        seen_here = dr.select(visible, throughput * mi.Color3f(emitter.eval(si, visible)), 0.0)
        emission += seen_here
        first += dr.select(depth == 0, seen_here, 0.0)
        bsdf = si.bsdf(ray)
        flags = bsdf.flags()
        specular = mi.has_flag(flags, mi.BSDFFlags.Delta) & ~mi.has_flag(flags, mi.BSDFFlags.Smooth)
        reached |= show & ~specular & mi.has_flag(flags, mi.BSDFFlags.Smooth)
        follow = show & specular & (depth + 1 < depth_limit) & (depth < bounce_limit)
        bs, w = bsdf.sample(ctx, si, rng.next_float32(follow), mi.Point2f(rng.next_float32(follow),
                                                                           rng.next_float32(follow)), follow)
        throughput = dr.select(follow, throughput * mi.Color3f(w), throughput)
        survive = dr.minimum(dr.max(throughput), 0.95)
        roulette = follow & (depth + 1 >= RR_DEPTH)
        follow &= ~roulette | (rng.next_float32(roulette) < survive)
        throughput = dr.select(roulette & follow, throughput / survive, throughput)
        follow &= dr.max(throughput) > 0
        ray = dr.select(follow, si.spawn_ray(si.to_world(bs.wo)), dr.select(hidden, si.spawn_ray(ray.d), ray))
        depth = dr.select(follow, depth + 1, depth)
        return ray, throughput, emission, first, follow | hidden, reached, surface, depth, rng

    n = dr.width(ray.o)
    chain = SpecularChain()
    chain.si = None
    if not hide_emitters and not any(is_specular(shape.bsdf()) for shape in scene.shapes()):
        # no surface to follow: the loop's first step alone, and its hit is the visible point
        si = scene.ray_intersect(ray)
        seen = mi.Bool(max_depth != 0)
        show = seen & si.is_valid()
        chain.ray, chain.throughput, chain.depth, chain.surface, chain.si = ray, dr.ones(mi.Color3f, n), \
            dr.zeros(mi.UInt32, n), show, si
        chain.emission = chain.first = dr.select(seen, mi.Color3f(si.emitter(scene).eval(si, seen)), 0.0)
        chain.reached = show & mi.has_flag(si.bsdf(ray).flags(), mi.BSDFFlags.Smooth)
        return chain
    with dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False):
        # loop state: the ray, its throughput, the emission seen so far and by the first
        # segment, the lanes still following, the lanes that reached a non-delta surface,
        # the first segment met a shown surface, the specular bounces, the random stream
        state = dr.while_loop((ray, dr.ones(mi.Color3f, n), dr.zeros(mi.Color3f, n), dr.zeros(mi.Color3f, n),
                               dr.full(mi.Bool, True, n), dr.full(mi.Bool, False, n), dr.full(mi.Bool, False, n),
                               dr.zeros(mi.UInt32, n), rng),
                              lambda *state: state[4], body)
    chain.ray, chain.throughput, chain.emission, chain.first, _, chain.reached, chain.surface, chain.depth, _ = state
    return chain


def is_specular(bsdf):
    """The scalar BSDF has only delta (or null) lobes: camera chains follow it."""
    flags = int(bsdf.flags()) if bsdf is not None else 0
    return bool(flags & int(mi.BSDFFlags.Delta)) and not flags & int(mi.BSDFFlags.Smooth)


def seen_emission(scene, ray, active=True):
    """The emission a camera ray sees at its first hit, or from the environment where it
    leaves the scene (the first segment's part of :func:`specular_chain`'s emission
    without ``hide_emitters``); the full surface interaction is computed only where the
    hit shape emits."""
    pi = scene.ray_intersect_preliminary(ray, False, active)
    valid = mi.Bool(active) & pi.is_valid()
    emits = valid & (pi.shape.emitter() != None)       # noqa: E711
    if scene.environment() is not None:
        emits |= mi.Bool(active) & ~pi.is_valid()
    si = pi.compute_surface_interaction(ray, mi.RayFlags.All, emits)
    return dr.select(emits, mi.Color3f(si.emitter(scene, emits).eval(si, emits)), 0.0)


def first_shown(scene, ray, hide_emitters, active=True):
    """The surface interaction of the first surface a camera ray shows: with
    ``hide_emitters`` (Mitsuba's meaning) the ray passes through area emitters, whose
    shapes are hidden with their emission."""
    si = scene.ray_intersect(ray, active)
    if not hide_emitters:
        return si

    def body(ray, si, active):
        hidden = active & si.is_valid() & (si.emitter(scene, active) != None)  # noqa: E711
        ray = dr.select(hidden, si.spawn_ray(ray.d), ray)
        si = dr.select(hidden, scene.ray_intersect(ray, hidden), si)
        return ray, si, hidden

    return dr.while_loop((ray, si, mi.Bool(active)), lambda ray, si, active: active, body)[1]


def unoccluded(scene, si, target, hide_emitters, active=True):
    """Per lane: nothing blocks the segment from ``si`` to the point ``target`` (hidden
    area emitters let it pass with ``hide_emitters``)."""
    if not hide_emitters:
        return mi.Bool(active) & ~scene.ray_test(si.spawn_ray_to(target), active)

    def body(at, clear, active):
        hit = scene.ray_intersect(at.spawn_ray_to(target), active)
        passes = active & hit.is_valid() & (hit.emitter(scene, active) != None)  # noqa: E711
        clear &= ~(active & hit.is_valid() & ~passes)
        at = dr.select(passes, hit, at)
        return at, clear, passes

    return dr.while_loop((si, mi.Bool(active), mi.Bool(active)), lambda at, clear, active: active, body)[1]
