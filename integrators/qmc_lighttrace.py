"""``qmc_lighttrace``: Keller's quasi-Monte Carlo light tracing in the radiosity setting
(A. Keller, "A quasi-Monte Carlo algorithm for the global illumination problem in the
radiosity setting", 1994): a particle preprocess that deposits power on triangles, then a
render with direct light and final gathering. The user reference is the class docstring.
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
    r"""
    .. _integrator-qmc_lighttrace:

    ``qmc_lighttrace`` (Keller 1994, quasi-Monte Carlo light tracing)
    -----------------------------------------------------------------

    Preprocess: N particle paths from the lights, path i driven by point i of a
    (2M + 4)-dimensional sequence (0-1: light choice and position, 2-3: direction, two per
    bounce), depositing power on every triangle hit up to M + 1 hits; L_k = rho_k /
    (pi |A_k|) x incoming power (eqs. 7-8), with optional adaptive termination (section
    4: batches until the area-weighted change Delta E stays below ``epsilon`` for
    ``patience`` batches). Render: eye rays from the sensor's sampler (mirrors and glass
    followed), emission + direct light (one light sample and one BSDF sample combined by
    multiple importance sampling: a light sample alone has infinite variance where
    emitting surfaces meet) + SR cosine final-gather rays reading L_k (a gather ray that
    meets a mirror follows it). The image contains paths of up to M + 3 segments:
    compare with ``case.expected(max_depth=M + 3)`` (or use a large M).

    .. pluginparameters::

     * - sequence
       - string
       - ``'sobol'``
       - ``'sobol'``, ``'halton'``, ``'faure'``, ``'lcg'`` (drand48), ``'independent'``
         (PCG32)
     * - scramble
       - bool
       - true
       - randomise the sequence with the scramble of ``mi_plugins.qmc`` (the render
         seed selects it); ``false``: the plain sequence
     * - max_depth
       - int
       - 6
       - M >= 0 (2M + 4 dimensions must fit the sequence: Halton/Faure M <= 126)
     * - samples
       - int
       - 100000
       - N >= 1 paths (when ``epsilon`` is not given)
     * - epsilon
       - float
       - none
       - > 0: adaptive termination threshold on Delta E
     * - batch
       - int
       - 1000
       - Delta N >= 1
     * - patience
       - int
       - 2
       - T >= 1 consecutive batches below ``epsilon``
     * - max_samples
       - int
       - 10^7
       - >= 1, cap for the adaptive termination
     * - gather_samples
       - int
       - 16
       - SR >= 1 final-gather rays per eye ray
     * - share_neighbors
       - bool
       - false
       - average gather results with the 8 neighbouring pixels seeing the same triangle
     * - mirror_depth
       - int
       - 8
       - >= 0 delta bounces followed by eye and gather rays
     * - hide_emitters
       - bool
       - false
       - do not show directly visible emitters

    Triangle meshes only (a clear error names a non-mesh shape). After a render,
    ``integrator.triangle_radiance`` (numpy (K, 3), L0 + reflected),
    ``reflected_radiance``, ``triangle_areas``, ``paths_used`` and ``delta_e_history``
    hold the preprocessing result; ``integrator.preprocess(scene, seed)`` runs it alone.
    Radiosity setting: the matrix reports cases with non-diffuse BSDFs as not applicable.

    .. code-block:: python

        {'type': 'qmc_lighttrace', 'sequence': 'sobol', 'max_depth': 29, 'epsilon': 1e-3, 'gather_samples': 16}

    .. code-block:: xml

        <integrator type="qmc_lighttrace"><string name="sequence" value="faure"/>
            <integer name="max_depth" value="29"/><integer name="samples" value="100000"/></integrator>
    """

    plugin = "qmc_lighttrace"

    def __init__(self, props):
        super().__init__(props)
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
