"""``qmc_lighttrace``'s particle phase for one range of its sequence: the paths
start .. start + count - 1 deposit their irradiance on the purely diffuse patch sides
they hit (``qmc_surfaces``), by hit count (``qmc_store.Layers``), in 64-bit signed
fixed point (one kernel per chunk). Ranges are independent: the phase of a render is
the sum of its ranges' deposits, which is also how a distributed render splits it.

Numbers of path i: point i of the sequence, dimensions 0-1 (light choice, reused, and
position), 2-3 (direction), then three per bounce (lobe choice, direction) for the
first ``sequence_depth`` bounces (Keller's M); later bounces draw from a PCG32 stream of
the particle's own (seeded by the render seed and i, so ranges give the same paths) and
play Russian roulette, so unbounded paths stay unbiased. At a bounce the particle's
power is multiplied by what Mitsuba's ``path`` weighs the same path with (the BSDF
evaluated with the camera-side direction as wi, adjoint shading-normal correction), so
any BSDF carries light on to the diffuse surfaces.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import sequences, seeds
from mi_plugins.patches.refinement import CHILDREN, child_index
from mi_plugins.light.sources import sample_light_rays
from mi_plugins.integrators.qmc_lighttrace.store import FixedPoint
from mi_plugins.solution.surfaces import Surfaces, arrival_factor, geometric_cosine, side_of

#: the most paths of one kernel (chunks bound the memory; the estimate is the same)
CHUNK = 1 << 20
#: first guess of the sum of all |deposits| of a chunk, in particle powers per path
#: (a chunk that exceeds it is traced again with a scale from its measured sum)
DEPOSIT_GUESS = 64.0
#: Russian roulette beyond the sequence's bounces: survival min(max |bounce weight|, this). A
#: bounce of weight w > this multiplies the survivor's power by w / this: the deposits' second
#: moment then sums (w^2 / this)^k over the bounces k, finite only while w^2 < this. At 0.95
#: (Mitsuba's ``path``) a room of reflectance 0.99 had infinite variance (image means 3.2 .. 4.8
#: across 6 seeds; 3.90 .. 3.94 at 0.99, 3x the time there); at 0.99 reflectances up to 0.995
#: keep it finite, and surfaces below 0.95 are not affected
MAX_SURVIVAL = 0.99


def dimensions(sequence_depth):
    """Sequence dimensions of a path: 4 + 3 per bounce."""
    return 4 + 3 * int(sequence_depth)


def trace_range(integ, scene, table, start, count, seed, children=False):
    """Deposits of paths start .. start + count - 1 of ``integ``'s sequence, in chunks of
    at most CHUNK paths summed in order: (irradiance flux per layer and patch side
    (layers, K, 2, 3), emitted power (3,)); zeros for a scene without emitters. With
    ``children``: per child of every patch side (layers, K, 2, 8, 3), and the sums of the
    squares of the deposits' luminance per child (K, 2, 8) as a third value
    (``mi_plugins.patches.refinement``)."""
    layers = integ.layers
    shape = (layers.count, table.count, 2) + ((CHILDREN,) if children else ()) + (3,)
    total, emitted, done, hits = np.zeros(shape), np.zeros(3), 0, np.zeros((table.count, 2, CHILDREN))
    surfaces = Surfaces(scene)
    while done < count and scene.emitters() and surfaces.any_diffuse:
        n = min(CHUNK, count - done)
        deposit, power, found = trace_particles(integ, scene, table, surfaces, start + done, n, int(seed),
                                                children=children)
        total, emitted, done = total + deposit, emitted + power, done + n
        if children:
            hits += found
    return (total, emitted, hits) if children else (total, emitted)


def trace_particles(integ, scene, table, surfaces, start, count, seed, scale=None, children=False):
    """Deposit the irradiance flux of paths start .. start + count - 1 (one kernel):
    (per layer and patch side, numpy (layers, K, 2, 3) (with ``children``: per child too,
    (layers, K, 2, 8, 3)); emitted power (3,); with ``children``, the sums of the squares of
    the deposits' luminance per child (K, 2, 8))."""
    layers, depth = integ.layers, integ.sequence_depth
    index = dr.arange(mi.UInt32, count) + dr.opaque(mi.UInt32, start)   # opaque: no recompiling
    dims = dimensions(depth)
    u = lambda d: sequences.sample(integ.sequence, index, d, dims=dims, scramble=integ.scramble,
                             seed=seeds.stream(seed, "particles"))
    # dimension 0 chooses the light and is reused for the position's first coordinate
    ray, power = sample_light_rays(scene, u(0), mi.Point2f(u(1), u(1)), mi.Point2f(u(2), u(3)))
    # (no offset: Mitsuba's intersection does not find the light itself again; measured on 2^20 rays of
    # a mesh, a rectangle and a sphere light; an offset along the ray lets rays that start within it of
    # an edge leave a closed room: 95 of 2^20 in Keller's cube with 1e-4)
    dr.eval(ray, power)
    emitted = np.array(power, dtype=np.float64)
    if scale is None:
        scale = FixedPoint.scale_for(DEPOSIT_GUESS * count * max(np.abs(emitted).max(initial=0.0), 1e-30))
    bins = CHILDREN if children else 1
    store = FixedPoint(layers.count * table.count * 6 * bins, scale)  # [(((layer K + patch) 2 + side) bins + child) 3 + c]
    hits_per_child = dr.zeros(mi.Float, table.count * 2 * bins)
    # the tail's stream: the render seed's, or a fixed one with the plain sequence; sequence i for path i
    # (seed(), not the constructor, which adds the lane: a range would draw other numbers than the whole)
    tail = mi.PCG32(count)
    tail.seed(dr.opaque(mi.UInt64, seeds.stream(seed if integ.scramble else 0, "particles", 1)), mi.UInt64(index))
    max_hits = mi.UInt32(layers.max_hits if layers.max_hits is not None else 0xFFFFFFFF)
    importance, radiance = mi.BSDFContext(mi.TransportMode.Importance), mi.BSDFContext(mi.TransportMode.Radiance)
    state = (ray, mi.Color3f(power), dr.zeros(mi.UInt32, count), dr.any(mi.Color3f(power) != 0),
             dr.zeros(mi.Float, count), tail)

    def body(ray, power, hits, active, spent, tail):
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid()
        hits = hits + 1
        bsdf = si.bsdf(ray)
        lit = surfaces.diffuse(si, active)
        value = power * arrival_factor(si)
        located = table.locate(si, lit)
        side = (located[0] * 2 + side_of(si)) * bins + (child_index(table, located, lit) if children else 0)
        slot = (layers.layer(hits) * (table.count * 2 * bins) + side) * 3
        for c in range(3):    # the three channels
            store.add(value[c], slot + c, lit)
        if children:        # (the squares of the deposits: the children's noise, mi_plugins.patches.refinement)
            brought = mi.luminance(value)
            dr.scatter_add(hits_per_child, brought * brought, side, lit)
        spent += dr.select(lit, dr.abs(value.x) + dr.abs(value.y) + dr.abs(value.z), 0.0)
        # the next bounce: the sequence's numbers for the first `depth` bounces, then the tail's
        active &= hits < max_hits
        from_sequence = hits <= depth
        dim = 4 + 3 * (dr.minimum(hits, max(depth, 1)) - 1)
        numbers = [dr.select(from_sequence, u(dim + k), tail.next_float32(active)) for k in range(3)]
        bs, weight = bsdf.sample(importance, si, numbers[0], mi.Point2f(numbers[1], numbers[2]), active)
        weight = adjoint_weight(bsdf, radiance, si, bs, weight, active)
        # Russian roulette beyond the sequence's bounces
        survive = dr.minimum(dr.max(dr.abs(weight)), MAX_SURVIVAL)
        roulette = active & ~from_sequence
        keep = ~roulette | (tail.next_float32(roulette) < survive)
        weight = dr.select(roulette, weight / dr.select(survive > 0, survive, 1.0), weight)
        active &= keep & (bs.pdf > 0)
        power = dr.select(active, power * weight, 0.0)
        return si.spawn_ray(si.to_world(bs.wo)), power, hits, active & dr.any(power != 0), spent, tail

    # without Dr.Jit's loop optimisation the body is traced once instead of twice (the renders of
    # small images spend most of their time tracing: -15 % CPU per render measured)
    with dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False):
        spent = dr.while_loop(state, lambda ray, power, hits, active, spent, tail: active, body)[4]
    total_abs = dr.sum(mi.Float64(spent))[0] if count else 0.0
    if not store.fits(total_abs):      # the guess was too low: trace again with room for what was deposited
        return trace_particles(integ, scene, table, surfaces, start, count, seed,
                               FixedPoint.scale_for(4.0 * total_abs), children)
    if children:
        return (store.values().reshape(layers.count, table.count, 2, CHILDREN, 3), emitted.sum(axis=1),
                np.array(hits_per_child, dtype=np.float64).reshape(table.count, 2, CHILDREN))
    return store.values().reshape(layers.count, table.count, 2, 3), emitted.sum(axis=1), None


def adjoint_weight(bsdf, ctx, si, bs, weight, active):
    """The particle's power factor of the bounce sampled as ``bs`` (Importance mode) at
    ``si`` (si.wi toward the light): as Mitsuba's ``path`` weighs the same path,
    f(wo, wi) |cos_sh(wi)| |cos_geo(wo)| / (|cos_geo(wi)| pdf) with the BSDF evaluated
    with wo as its wi (``ctx``: Radiance mode); delta and null lobes, which cannot be
    evaluated, keep their Importance-mode weight with the adjoint shading-normal
    correction (Veach 1997, p. 158). A sample of weight 0 is none (its factor 0):
    ``roughdielectric`` keeps its lobe's pdf for directions that crossed to the other
    lobe's side, where eval() is the other lobe's (docs/findings.md); ``bs.pdf`` is the
    density of the samples of non-zero weight."""
    delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    at = mi.SurfaceInteraction3f(si)
    at.wi = bs.wo
    smooth = active & ~delta & (bs.pdf > 0) & dr.any(mi.Color3f(weight) != 0)
    f = mi.Color3f(bsdf.eval(ctx, at, si.wi, smooth))
    cos_in = dr.abs(geometric_cosine(si, si.wi))
    cos_out = dr.abs(geometric_cosine(si, bs.wo))
    ok = smooth & (cos_in > 0)
    smooth_w = dr.select(ok, f * cos_out / dr.select(ok, cos_in * bs.pdf, 1.0), 0.0)
    correction = dr.abs(mi.Frame3f.cos_theta(si.wi) * cos_out
                        / dr.maximum(dr.abs(mi.Frame3f.cos_theta(bs.wo)) * cos_in, 1e-12))
    return dr.select(delta, mi.Color3f(weight) * correction, smooth_w)
