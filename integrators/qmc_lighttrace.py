"""``qmc_lighttrace``: Keller's quasi-Monte Carlo light tracing in the radiosity setting.

Implements A. Keller, "A quasi-Monte Carlo algorithm for the global illumination
problem in the radiosity setting" (1994):

1. *Preprocess*: N particle paths leave the light sources, path i driven by point i
   of a (2M + 4)-dimensional sequence (dimensions 0-1: light choice and position,
   2-3: emission direction, then two per bounce). Every hit deposits the particle's
   power on the triangle hit, up to M + 1 hits. The mean reflected radiance of
   triangle k is L_k = rho_k / (pi |A_k|) * (incoming power) (eqs. 7-8); rho is the
   diffuse reflectance at the hit point. Optional adaptive termination (section 4):
   batches of ``batch`` paths until the area-weighted change Delta E of the L_k
   stays below ``epsilon`` for ``patience`` consecutive batches.
2. *Render*: per pixel ``spp`` eye rays from the sensor's sampler (ideal mirrors and
   dielectrics followed, ``mirror_depth`` bounces at most); at the first non-delta hit,
   L = Le + direct light (one light sample and one BSDF sample, combined by multiple
   importance sampling: a light sample alone has infinite variance where emitting
   surfaces meet) + indirect light from ``gather_samples`` cosine-distributed
   final-gather rays that read the L_k of the triangle they reach (a gather ray that
   meets a mirror follows it and takes the full radiance behind it), optionally averaged
   over the 8 neighbouring pixels that see the same triangle.

Truncation: the image contains the light of paths with up to M + 3 segments
(Mitsuba's ``max_depth = M + 3``): the analytic checks compare with that value.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Default
     - Description
   * - sequence
     - string
     - 'sobol'
     - 'sobol', 'halton', 'faure', 'lcg' (drand48) or 'independent' (PCG32)
   * - scramble
     - bool
     - true
     - Owen scrambling (Sobol), random digit permutations (Halton), Faure's
       permutations with random digit shifts (Faure); seeds for lcg / independent; the
       render seed selects the randomisation
   * - max_depth
     - int >= 0
     - 6
     - M: particle paths deposit on up to M + 1 hits
   * - samples
     - int >= 1
     - 100000
     - N, particle paths (when ``epsilon`` is not given)
   * - epsilon
     - float > 0
     - (none)
     - adaptive termination threshold on Delta E
   * - batch
     - int >= 1
     - 1000
     - Delta N, paths per batch of the adaptive termination
   * - patience
     - int >= 1
     - 2
     - T, consecutive batches below epsilon
   * - max_samples
     - int >= 1
     - 10000000
     - upper bound of N for the adaptive termination
   * - gather_samples
     - int >= 1
     - 16
     - SR, final-gather rays per eye ray
   * - share_neighbors
     - bool
     - false
     - average gather results with the 8 neighbouring pixels that see the same triangle
   * - mirror_depth
     - int >= 0
     - 8
     - how many delta (mirror/glass) bounces eye rays follow

Triangle meshes only; after a render, ``triangle_radiance`` (numpy (K, 3): total
radiance L0 + reflected of every triangle), ``reflected_radiance``, ``triangle_areas``
and ``paths_used`` hold the preprocessing result (also returned by :meth:`preprocess`).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import qmc, seeds
from mi_plugins.integrators.camera import specular_chain
from mi_plugins.integrators.core import CoreIntegrator
from mi_plugins.meshtable import MeshTable
from mi_plugins.params import Params
from mi_plugins.sampling import direct_light

SEQUENCES = ("sobol", "halton", "faure", "lcg", "independent")


class QMCLightTraceIntegrator(CoreIntegrator):
    plugin = "qmc_lighttrace"

    def __init__(self, props):
        p = Params(props, "qmc_lighttrace")
        hide_emitters = p.bool("hide_emitters", False)   # before the base class reads it with its own check
        super().__init__(props)
        self.hide_emitters = hide_emitters
        self.sequence = p.choice("sequence", "sobol", SEQUENCES)
        self.scramble = p.bool("scramble", True)
        self.max_depth = p.int("max_depth", 6, lo=0)
        self.samples = p.int("samples", 100000, lo=1)
        self.epsilon = p.float("epsilon", None, lo=0, lo_open=True, note="optional: adaptive termination")
        self.batch = p.int("batch", 1000, lo=1)
        self.patience = p.int("patience", 2, lo=1)
        self.max_samples = p.int("max_samples", 10000000, lo=1)
        self.gather_samples = p.int("gather_samples", 16, lo=1)
        self.share_neighbors = p.bool("share_neighbors", False)
        self.mirror_depth = p.int("mirror_depth", 8, lo=0)
        dims = 2 * self.max_depth + 4
        if self.sequence in ("sobol", "halton", "faure") and dims > qmc.max_dim(self.sequence):
            raise p.conflict(("max_depth", "sequence"),
                             "max_depth <= %d with sequence '%s': max_depth=%d needs %d dimensions; sequence '%s' "
                             "has %d" % ((qmc.max_dim(self.sequence) - 4) // 2, self.sequence, self.max_depth, dims,
                                         self.sequence, qmc.max_dim(self.sequence)))
        self.triangle_radiance = self.reflected_radiance = self.triangle_areas = None
        self.paths_used = 0
        self.delta_e_history = []

    # ------------------------------------------------------------------ preprocessing
    def _u(self, index, dim, seed):
        return qmc.sample(self.sequence, index, dim, dims=2 * self.max_depth + 4, scramble=self.scramble, seed=seed)

    def _trace_particles(self, scene, table, start, count, seed):
        """Deposit the power of paths start .. start + count - 1; returns (reflected power
        per triangle as numpy (K, 3), sum of emitted power weights (3,))."""
        # opaque offset: every batch reuses the same kernels instead of baking `start` in
        index = dr.arange(mi.UInt32, count) + dr.opaque(mi.UInt32, start)
        u = lambda d: self._u(index, d, seed)
        # light choice by dimension 0, rescaled and reused with dimension 1 for the position
        emitter_index, choice_weight, u0 = scene.sample_emitter(u(0))
        emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), emitter_index)
        ray, power = emitter.sample_ray(0.0, 0.5, mi.Point2f(u0, u(1)), mi.Point2f(u(2), u(3)))
        power *= choice_weight
        emitted = np.array(power, dtype=np.float64).sum(axis=1)
        deposit = [dr.zeros(mi.Float, table.count) for _ in range(3)]
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        active = dr.any(power != 0)
        for bounce in range(self.max_depth + 1):  # a loop over path vertices: every path advances together
            si = scene.ray_intersect(ray, active)
            active &= si.is_valid()
            bsdf = si.bsdf(ray)
            tri = table.triangle_index(si.shape, si.prim_index)
            rho = bsdf.eval_diffuse_reflectance(si, active)
            reflected = power * rho
            for c in range(3):
                dr.scatter_reduce(dr.ReduceOp.Add, deposit[c], reflected[c], tri, active)
            if bounce == self.max_depth:
                break
            d0, d1 = 4 + 2 * bounce, 5 + 2 * bounce
            bs, weight = bsdf.sample(ctx, si, u(d0), mi.Point2f(u(d0), u(d1)), active)
            power *= weight
            active &= dr.any(power != 0)
            ray = si.spawn_ray(si.to_world(bs.wo))
            dr.eval(ray, power, active, deposit)
        return np.stack([np.array(d, dtype=np.float64) for d in deposit], axis=1), emitted

    def preprocess(self, scene, seed=0):
        """Run the particle phase; returns (triangle_radiance (K, 3), triangle_areas (K,))."""
        table = MeshTable(scene, "qmc_lighttrace")
        self.table = table
        areas = table.areas_np
        emission = self._triangle_emission(scene, table)
        seed = int(seed)
        total = np.zeros((table.count, 3))
        emitted = np.zeros(3)
        self.delta_e_history = []
        if self.epsilon is None:
            done = 0
            while done < self.samples:  # chunks bound the memory; the estimate is the same
                n = min(1 << 20, self.samples - done)
                dep, em = self._trace_particles(scene, table, done, n, seed)
                total += dep
                emitted += em
                done += n
        else:
            done, below, previous = 0, 0, None
            norm = None
            while done < self.max_samples:
                n = min(self.batch, self.max_samples - done)
                dep, em = self._trace_particles(scene, table, done, n, seed)
                total += dep
                emitted += em
                done += n
                current = total / done / (np.pi * areas[:, None])
                if norm is None:
                    norm = max(float(np.sum(emission.mean(axis=1) * areas)), 1e-30)
                if previous is not None:
                    d = np.linalg.norm(current - previous, axis=1)
                    delta_e = np.sqrt(np.sum(d * d * areas) / np.sum(areas)) / norm
                    self.delta_e_history.append(delta_e)
                    below = below + 1 if delta_e < float(self.epsilon) else 0
                    if below >= self.patience:
                        break
                previous = current
        self.paths_used = done
        self.reflected_radiance = total / done / (np.pi * areas[:, None])
        self.triangle_radiance = self.reflected_radiance + emission
        self.triangle_areas = areas
        return self.triangle_radiance, areas

    def _triangle_emission(self, scene, table):
        """Diffuse-equivalent emitted radiance of each triangle (at its centroid, along the normal)."""
        tri = dr.arange(mi.UInt32, table.count)
        si = table.surface_interaction(tri, mi.Point2f(1.0 / 3.0, 1.0 / 3.0))
        si.wi = mi.Vector3f(0, 0, 1)
        emitter = si.emitter(scene)
        value = emitter.eval(si, emitter != None)  # noqa: E711 (Dr.Jit pointer array)
        return np.array(value, dtype=np.float64).T

    # ------------------------------------------------------------------ rendering
    def render_frame(self, frame):
        scene = frame.scene
        self.preprocess(scene, frame.seed)
        reflected = mi.Color3f(*(mi.Float(self.reflected_radiance[:, c]) for c in range(3)))
        frame.camera_passes(frame.spp, 1)
        cam = frame.camera_pass()
        rng = seeds.pcg(cam.count, frame.seed, "camera_path")
        path = specular_chain(scene, cam.ray, rng, max_bounces=self.mirror_depth, hide_emitters=self.hide_emitters)
        si = scene.ray_intersect(path.ray, path.reached)
        active = path.reached & si.is_valid()
        bsdf = si.bsdf(path.ray)
        direct = self._direct(scene, cam.sampler, si, bsdf, active)
        gather = self._gather(scene, cam.sampler, rng, si, bsdf, active, reflected)
        if self.share_neighbors:
            tri = dr.select(active, self.table.triangle_index(si.shape, si.prim_index), 0xFFFFFFFF)
            gather = self._share(gather, tri, cam)
        frame.put_camera(cam, path.emission + path.throughput * (direct + gather))

    def _direct(self, scene, sampler, si, bsdf, active):
        """L0 reflected once (T_f L0): one light sample and one BSDF sample, combined by
        multiple importance sampling (a light sample alone has infinite variance where
        emitting surfaces meet, e.g. at the edges of a furnace)."""
        light_sample = sampler.next_2d()
        return direct_light(scene, si, bsdf, light_sample, active, (sampler.next_1d(), sampler.next_2d()))

    def _gather(self, scene, sampler, rng, si, bsdf, active, reflected):
        """SR cosine-distributed final-gather rays reading the reflected radiance L_k of the
        triangle they reach; a ray that reaches a purely specular surface follows it and
        takes the full radiance found behind it (its emission is not covered by the light
        sample)."""
        table, ctx = self.table, mi.BSDFContext()
        gather = dr.zeros(mi.Color3f, dr.width(si.p))
        for _ in range(self.gather_samples):  # SR gather rays (a small constant)
            d = mi.warp.square_to_cosine_hemisphere(sampler.next_2d())
            pdf = mi.warp.square_to_cosine_hemisphere_pdf(d)
            ok = active & (pdf > 0)
            weight = mi.Color3f(bsdf.eval(ctx, si, d, ok)) / dr.select(ok, pdf, 1.0)
            ray = si.spawn_ray(si.to_world(d))
            chain = specular_chain(scene, ray, rng, max_bounces=self.mirror_depth)
            via_mirror = ok & (chain.depth > 0)
            end = scene.ray_intersect(chain.ray, ok & chain.reached)
            k = table.triangle_index(end.shape, end.prim_index)
            stored = dr.gather(mi.Color3f, reflected, k, ok & chain.reached & end.is_valid())
            stored = dr.select(ok & chain.reached & end.is_valid(), stored, 0.0)
            value = dr.select(via_mirror, chain.emission + chain.throughput * stored, stored)
            gather += dr.select(ok, weight * value, 0.0)
        return gather / self.gather_samples

    def _share(self, gather, tri, cam):
        """Average each gather result with those of the 8 neighbouring pixels (same sample
        number) whose eye ray hit the same triangle."""
        width, height, spp = cam.grid_width, cam.grid_height, cam.per_pixel
        lane = dr.arange(mi.UInt32, cam.count)
        pixel, s = lane // spp, lane % spp
        x, y = mi.Int32(pixel % width), mi.Int32(pixel // width)
        total, count = dr.zeros(mi.Color3f, dr.width(lane)), dr.zeros(mi.Float, dr.width(lane))
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                nx, ny = x + dx, y + dy
                inside = (nx >= 0) & (nx < width) & (ny >= 0) & (ny < height)
                other = mi.UInt32(dr.select(inside, ny * width + nx, 0)) * spp + s
                same = inside & (dr.gather(mi.UInt32, tri, other, inside) == tri) & (tri != 0xFFFFFFFF)
                total += dr.select(same, dr.gather(mi.Color3f, gather, other, same), 0.0)
                count += dr.select(same, 1.0, 0.0)
        return dr.select(count > 0, total / dr.maximum(count, 1.0), gather)

    def to_string(self):
        return "QMCLightTraceIntegrator[sequence=%s, max_depth=%d, samples=%d]" % (
            self.sequence, self.max_depth, self.samples)
