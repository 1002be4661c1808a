"""The camera side of ``qmc_lighttrace``: eye rays, the visible point, final gathering.

An eye ray follows purely specular surfaces (:func:`~mi_plugins.render.camera.specular_chain`) to the first
surface x with a smooth lobe, the *visible point*. There: one light sample and
``gather_samples`` (SR) samples of x's BSDF (cosine rays on diffuse surfaces), combined
by multiple importance sampling (power heuristic, the light sample against SR BSDF
samples). Each gather sample continues (:meth:`CameraPaths.continuation`):

- at its hit y, the emission seen, MIS-weighted against the previous vertex's light
  sample (weight 1 after a delta or null lobe);
- y purely diffuse (``qmc_surfaces``): y's direct light (a light sample and a BSDF
  sample, MIS) plus the stored light of particles at their hit k >= 2, read from the
  table the path's remaining depth allows (``qmc_store.Layers``); the path ends;
- y non-diffuse (glossy, delta, null, mixed lobes), or on a patch at a narrow gap's
  mouth (``Surfaces.readable``): a light sample (MIS) and a BSDF sample that continues
  the path, Russian roulette after ``RR_DEPTH`` segments.

Every vertex counts its segments as Mitsuba's ``path`` does (``max_depth`` D: emission
at segment <= D, a light sample or a continuation only below D), so the image agrees
with ``path`` at every depth.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.base import seeds
from mi_plugins.light.sources import pdf_emitter_direction, sample_emitter_direction
from mi_plugins.render.camera import UNBOUNDED, specular_chain
from mi_plugins.solution.surfaces import patch_side
from mi_plugins.solution.surfaces import reflectance_toward

#: camera-side continuations play Russian roulette from this many segments on
#: (survival min(max throughput, 0.95)), as Mitsuba's path does
RR_DEPTH = 5


def mis(pdf_a, pdf_b):
    """Power heuristic a^2 / (a^2 + b^2); 0 where not a number (an infinite light pdf,
    see ``mi_plugins.light.direct``)."""
    a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
    w = a2 / (a2 + b2)
    return dr.select((a2 > 0) & dr.isfinite(w), w, 0.0)


def light_sample(scene, si, bsdf, sample, active, bsdf_samples=1.0):
    """One visibility-tested emitter sample (the package's, :mod:`mi_plugins.light.sources`)
    reflected at ``si`` toward si.wi, MIS-weighted against ``bsdf_samples`` BSDF samples
    (delta lights: weight 1)."""
    ds, em_weight = sample_emitter_direction(scene, si, sample, active)
    ok = active & (ds.pdf > 0)
    f, pdf = bsdf.eval_pdf(mi.BSDFContext(), si, si.to_local(ds.d), ok)
    w = dr.select(ds.delta, 1.0, mis(ds.pdf, bsdf_samples * pdf))
    return dr.select(ok, mi.Color3f(f) * mi.Color3f(em_weight) * w, 0.0)


class FlatTables:
    """The stored light of the read tables, constant per patch side: ``tables`` (Color3f,
    table t of patch side ps at t x 2K + ps) of ``table``'s K patches."""

    def __init__(self, table, tables):
        self.table, self.tables = table, tables

    def __call__(self, hit, index, active):
        """The irradiance of table ``index`` at hits ``hit`` (diffuse patch sides)."""
        return self.at(patch_side(self.table, hit), index, active)

    def at(self, side, index, active):
        """The irradiance of table ``index`` on patch sides ``side`` (2 x patch + side)."""
        return dr.gather(mi.Color3f, self.tables, index * (2 * self.table.front_count) + side, active)


class OwnStream:
    """A PCG32 stream ``rng`` drawn as a sampler draws (:meth:`next_1d`, :meth:`next_2d`)."""

    def __init__(self, rng):
        self.rng = rng

    def next_1d(self, active=True):
        return self.rng.next_float32(active)

    def next_2d(self, active=True):
        return mi.Point2f(self.next_1d(active), self.next_1d(active))


def draw_numbers(sampler, gather_samples, active=True):
    """The numbers of a gather from ``sampler`` (a camera pass's): the light sample's
    Point2f, then (Float, Point2f) for each of the ``gather_samples`` BSDF samples."""
    return [sampler.next_2d(active)] + [(sampler.next_1d(active), sampler.next_2d(active))
                                        for _ in range(int(gather_samples))]


class CameraPaths:
    """Camera paths of one render: ``stored`` (a reader of the stored irradiance, e.g.
    :class:`FlatTables`), ``layers`` (``qmc_store.Layers``: which table a path may read),
    ``max_depth`` (-1: unbounded), ``mirror_depth`` (-1: unbounded; delta bounces followed
    by the eye ray, and by each gather continuation)."""

    def __init__(self, scene, table, surfaces, layers, stored, max_depth, mirror_depth, hide_emitters):
        self.scene, self.table, self.surfaces, self.layers, self.stored = scene, table, surfaces, layers, stored
        self.depth = UNBOUNDED if max_depth < 0 else int(max_depth)
        self.max_depth, self.mirror_depth, self.hide_emitters = int(max_depth), int(mirror_depth), hide_emitters

    def visible_points(self, cam, seed, evaluate=True):
        """The eye rays of camera pass ``cam``: (chain, si at the visible point, its BSDF,
        segments used to reach it (UInt32), active); evaluated in one kernel unless
        ``evaluate`` is false (a caller that fuses them into its own kernel)."""
        scene = self.scene
        rng = seeds.pcg(cam.count, seed, "camera_path")
        chain = specular_chain(scene, cam.ray, rng, self.max_depth, self.mirror_depth, self.hide_emitters)
        si = chain.si if chain.si is not None else scene.ray_intersect(chain.ray, chain.reached)
        used = chain.depth + 1
        active = chain.reached & si.is_valid() & (used < self.depth)
        bsdf = si.bsdf(chain.ray)
        if evaluate:
            dr.eval(chain.emission, chain.throughput, chain.surface, si, bsdf, used, active)   # the chain's one kernel
        return chain, si, bsdf, used, active

    def estimate(self, cam, seed, gather_samples):
        """(chain, si, light, gathered) at the visible points: the light sample's share of
        the direct light, and the average of the gather samples (the rest of the direct
        light, seen at their first hit, and everything beyond; one sum, since the two parts
        of a sample are strongly anti-correlated where emitting surfaces also reflect)."""
        chain, si, bsdf, used, active = self.visible_points(cam, seed)
        light, gathered = self.gather(cam, seed, gather_samples, si, bsdf, used, active)
        return chain, si, light, gathered

    def gather(self, cam, seed, gather_samples, si, bsdf, used, active, drawn=None):
        """(light, gathered) at visible points ``si`` (lanes ``active``) of camera pass
        ``cam`` (None: lanes of their own, numbers from ``drawn`` where given (the light
        sample's Point2f, then (Float, Point2f) per gather sample, e.g.
        :func:`draw_numbers`), else from ``seed``'s stream instead of the camera sampler);
        the SR gather samples of an eye ray are SR consecutive lanes of one loop."""
        sr, n = int(gather_samples), dr.width(active)
        if cam is not None:
            drawn = draw_numbers(cam.sampler, sr, active)
            cam.sampler.schedule_state()
        elif drawn is None:
            drawn = draw_numbers(OwnStream(seeds.pcg(n, seed, "camera_path", 3)), sr, active)
        light = light_sample(self.scene, si, bsdf, drawn[0], active, float(sr))
        # the gather samples' numbers, lane i * SR + j for sample j of eye lane i
        numbers = [dr.zeros(mi.Float, n * sr) for _ in range(3)]
        slots = dr.arange(mi.UInt32, n) * sr
        for j, (u1, u2) in enumerate(drawn[1:]):        # SR samples (a small constant)
            for target, value in zip(numbers, (u1, u2.x, u2.y)):
                dr.scatter(target, value, slots + j)
        dr.eval(light, numbers)
        eye = dr.arange(mi.UInt32, n * sr) // sr
        at, go = dr.gather(mi.SurfaceInteraction3f, si, eye), dr.gather(mi.Bool, active, eye)
        vertex = dr.gather(mi.BSDFPtr, bsdf, eye, go)
        bs, weight = vertex.sample(mi.BSDFContext(), at, numbers[0], mi.Point2f(numbers[1], numbers[2]), go)
        go &= (bs.pdf > 0) & dr.any(mi.Color3f(weight) != 0)
        rng = seeds.pcg(n * sr, seed, "camera_path", 1)
        result = self.continuation(at, bs, mi.Color3f(weight), dr.gather(mi.UInt32, used, eye), go, rng, sr)
        dr.eval(result)    # one kernel (block_sum of each channel alone would launch the loop three times)
        gathered = mi.Color3f(*(dr.block_sum(result[c], sr) / sr for c in range(3)))
        return light, gathered

    def continuation(self, si, bs, weight, used, active, rng, sr=1):
        """The radiance a BSDF sample ``bs`` (weight ``weight``) of vertex ``si`` brings
        back, the vertex having used ``used`` segments; the sample's pdf counts ``sr``
        times in the MIS weight of the emission it reaches (the vertex's light sample
        was weighted against sr BSDF samples)."""
        scene, surfaces, layers, stored = self.scene, self.surfaces, self.layers, self.stored
        depth = mi.UInt32(self.depth)
        mirrors = mi.UInt32(self.mirror_depth if self.mirror_depth >= 0 else UNBOUNDED)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        n = dr.width(active)
        active = mi.Bool(active) & (dr.select(delta, 1, 0) <= mirrors)
        state = (si.spawn_ray(si.to_world(bs.wo)), dr.select(active, weight, 0.0), active,
                 dr.full(mi.Bool, False, n), mi.UInt32(used), mi.SurfaceInteraction3f(si),
                 bs.pdf * sr, delta, dr.select(delta, 1, 0) + dr.zeros(mi.UInt32, n), rng, dr.zeros(mi.Color3f, n))

        def body(ray, beta, active, last, used, prev, prev_pdf, prev_delta, mirrored, rng, result):
            hit = scene.ray_intersect(ray, active)
            segment = used + 1
            # the emission seen, MIS-weighted against the previous vertex's light sample
            emitter = hit.emitter(scene, active)
            light_pdf = pdf_emitter_direction(scene, prev, mi.DirectionSample3f(scene, hit, prev), active & ~prev_delta)
            w = dr.select(prev_delta, 1.0, mis(prev_pdf, light_pdf))
            result += dr.select(active, beta * mi.Color3f(emitter.eval(hit, active)) * w, 0.0)
            go = active & hit.is_valid() & ~last & (segment < depth)
            bsdf = hit.bsdf(ray)
            diffuse = surfaces.readable(hit, go)      # (a patch at a gap's mouth: continue)
            # a diffuse hit: the stored light of particle hits k >= 2 that fit in the depth left
            index, readable = layers.read_table(mi.Int32(depth) - mi.Int32(segment))
            read = go & diffuse & readable
            # tables that carry the direct light too (ray_bundle without first_shot) hold all
            # of it where read: no light sample there, and no segment on for the emission
            sample = go & ~read if layers.carries_direct else go
            result += beta * light_sample(scene, hit, bsdf, mi.Point2f(rng.next_float32(go), rng.next_float32(go)),
                                          sample)
            result += dr.select(read, beta * stored(hit, index, read) * reflectance_toward(bsdf, hit, read), 0.0)
            # the next segment: after a diffuse hit only to see its emission (MIS)
            bs, weight = bsdf.sample(mi.BSDFContext(), hit, rng.next_float32(go),
                                     mi.Point2f(rng.next_float32(go), rng.next_float32(go)), go)
            delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            beta = beta * mi.Color3f(weight)
            survive = dr.minimum(dr.max(dr.abs(beta)), 0.95)
            roulette = go & ~diffuse & (segment >= RR_DEPTH)
            go &= ~roulette | (rng.next_float32(roulette) < survive)
            beta = dr.select(roulette, beta / dr.select(survive > 0, survive, 1.0), beta)
            mirrored = mirrored + dr.select(delta, 1, 0)
            go &= (bs.pdf > 0) & dr.any(beta != 0) & (mirrored <= mirrors)
            if layers.carries_direct:
                go &= ~read
            return (hit.spawn_ray(hit.to_world(bs.wo)), beta, go, diffuse, segment,
                    mi.SurfaceInteraction3f(hit), bs.pdf, delta, mirrored, rng, result)

        with dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False):     # (traced once: see qmc_particles)
            return dr.while_loop(state, lambda *s: s[2], body)[10]

    def first_patch_side(self, si, active):
        """Patch side of the visible points on purely diffuse surfaces (neighbour
        sharing), 0xFFFFFFFF elsewhere."""
        diffuse = self.surfaces.diffuse(si, active)
        return dr.select(diffuse, patch_side(self.table, si), 0xFFFFFFFF)

