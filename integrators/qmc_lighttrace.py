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
2. *Render*: per pixel ``spp`` eye rays (ideal mirrors and dielectrics followed);
   at the first non-delta hit, L = Le + direct light by light sampling + indirect
   light from ``gather_samples`` cosine-distributed final-gather rays that read the
   L_k of the triangle they hit (optionally averaged over the 8 neighbouring pixels
   that see the same triangle).

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
     - Owen scrambling (Sobol) / random digit permutations (Halton, Faure); seeds
       for lcg / independent; the render seed selects the randomisation
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

from mi_plugins import qmc
from mi_plugins.sampling import direct_light
from mi_plugins.meshtable import MeshTable
from mi_plugins.integrators.stochastic_common import check_variant
from mi_plugins.params import Params

SEQUENCES = ("sobol", "halton", "faure", "lcg", "independent")


class QMCLightTraceIntegrator(mi.SamplingIntegrator):
    def __init__(self, props):
        super().__init__(props)
        check_variant("qmc_lighttrace")
        p = Params(props, "qmc_lighttrace")
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
    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        self.preprocess(scene, seed)
        reflected = [mi.Float(self.reflected_radiance[:, c]) for c in range(3)]
        film = sensor.film()
        size = film.crop_size()
        width, height = int(size[0]), int(size[1])
        spp = spp or sensor.sampler().sample_count()
        n = width * height * spp
        sampler = sensor.sampler().clone()
        sampler.set_sample_count(spp)
        sampler.set_samples_per_wavefront(spp)
        sampler.seed(seed, n)
        lane = dr.arange(mi.UInt32, n)
        pixel = lane // spp
        px, py = pixel % width, pixel // width
        offset = sampler.next_2d()
        pos = mi.Point2f((mi.Float(px) + offset.x) / width, (mi.Float(py) + offset.y) / height)
        ray, ray_weight = sensor.sample_ray(0.0, sampler.next_1d(), pos, sampler.next_2d())
        value, gather, tri = self._eye_radiance(scene, sampler, ray, reflected)
        if self.share_neighbors:
            gather = self._share(gather, tri, width, height, spp)
        value = (value + gather) * ray_weight
        image = dr.zeros(mi.Color3f, width * height)
        dr.scatter_reduce(dr.ReduceOp.Add, image, value / spp, pixel)
        arr = np.array(image, dtype=np.float32).T.reshape(height, width, 3)
        return mi.TensorXf(arr)

    def _eye_radiance(self, scene, sampler, ray, reflected):
        """(direct part, final-gather part, first non-delta triangle) of each eye ray."""
        table = self.table
        ctx = mi.BSDFContext()
        throughput = dr.ones(mi.Color3f, dr.width(ray.o))
        si = scene.ray_intersect(ray)
        active = si.is_valid()
        for _ in range(self.mirror_depth):  # follow ideal mirrors / glass
            bsdf = si.bsdf(ray)
            delta = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Delta)
            if not dr.any(delta):
                break
            bs, weight = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), delta)
            ray = dr.select(delta, si.spawn_ray(si.to_world(bs.wo)), ray)
            throughput = dr.select(delta, throughput * weight, throughput)
            si = dr.select(delta, scene.ray_intersect(ray, delta), si)
            active &= si.is_valid()
            dr.eval(ray, throughput, si, active)
        bsdf = si.bsdf(ray)
        emitted = dr.select(active, si.emitter(scene).eval(si, active), 0.0)
        direct = self._direct(scene, sampler, si, bsdf, active)
        gather = dr.zeros(mi.Color3f, dr.width(si.p))
        for _ in range(self.gather_samples):  # SR gather rays (a small constant)
            d = mi.warp.square_to_cosine_hemisphere(sampler.next_2d())
            pdf = mi.warp.square_to_cosine_hemisphere_pdf(d)
            f = bsdf.eval(ctx, si, d, active)
            hit = scene.ray_intersect(si.spawn_ray(si.to_world(d)), active & (pdf > 0))
            k = table.triangle_index(hit.shape, hit.prim_index)
            ok = hit.is_valid() & active & (pdf > 0)
            stored = mi.Color3f(*[dr.gather(mi.Float, reflected[c], k, ok) for c in range(3)])
            gather += dr.select(ok, f / dr.select(ok, pdf, 1.0) * stored, 0.0)
        gather /= self.gather_samples
        tri = dr.select(active, table.triangle_index(si.shape, si.prim_index), 0xFFFFFFFF)
        return throughput * (emitted + direct), throughput * gather, tri

    def _direct(self, scene, sampler, si, bsdf, active):
        """One light sample: L0 reflected once (T_f L0), visibility-tested."""
        return direct_light(scene, si, bsdf, sampler.next_2d(), active)

    def _share(self, gather, tri, width, height, spp):
        """Average each gather result with those of the 8 neighbouring pixels (same sample
        number) whose eye ray hit the same triangle."""
        lane = dr.arange(mi.UInt32, width * height * spp)
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

    def sample(self, scene, sampler, ray, medium=None, active=True):
        raise RuntimeError("qmc_lighttrace renders whole images (preprocess + final gathering); "
                           "use mi.render(scene)")

    def to_string(self):
        return "QMCLightTraceIntegrator[sequence=%s, max_depth=%d, samples=%d]" % (
            self.sequence, self.max_depth, self.samples)
