"""``qmc_lighttrace``: Keller's quasi-Monte Carlo light tracing in the radiosity setting
(A. Keller, "A quasi-Monte Carlo algorithm for the global illumination problem in the
radiosity setting", 1994): a particle preprocess that deposits power on patches, then a
render with direct light and final gathering. The user reference is the class docstring.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import qmc, seeds
from mi_plugins.integrators.camera import specular_chain
from mi_plugins.integrators.core import CoreIntegrator
from mi_plugins.integrators.neighbours import share_with_neighbours
from mi_plugins.integrators.qmc_particles import patch_side, trace_range
from mi_plugins.meshtable import MeshTable, patch_parameters
from mi_plugins.params import Params
from mi_plugins.sampling import direct_light

SEQUENCES = ("sobol", "halton", "faure", "lcg", "independent")


class QMCLightTraceIntegrator(CoreIntegrator):
    r"""
    .. _integrator-qmc_lighttrace:

    ``qmc_lighttrace`` (Keller 1994, quasi-Monte Carlo light tracing)
    -----------------------------------------------------------------

    Preprocess: N particle paths from the lights (surfaces, environment, delta lights),
    path i driven by point i of a (2M + 4)-dimensional sequence (0-1: light choice and
    position, 2-3: direction, two per bounce), depositing power on every patch hit up to
    M + 1 hits, per side (a one-sided BSDF hit from behind absorbs; ``twosided`` keeps
    its sides apart), in 64-bit fixed point (a seed gives the same patch radiances every
    time; only the film's float splats may differ in the last bits under load);
    L_k = rho_k / (pi |A_k|) x incoming power (eqs. 7-8); optional adaptive termination
    (section 4: batches until the area-weighted change Delta E, relative to the emitted
    power / pi, stays below ``epsilon`` for ``patience`` batches). Render: eye rays from the
    sensor's sampler (mirrors and glass followed), emission + direct light (one light
    sample and one BSDF sample combined by multiple importance sampling: a light sample
    alone has infinite variance where emitting surfaces meet) + SR cosine final-gather rays
    reading L_k of the side they reach (following mirrors). The image contains paths of up
    to M + 3 segments: compare with ``case.expected(max_depth=M + 3)`` (or use a large M).

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
       - 29
       - M >= 0 (2M + 4 dimensions must fit the sequence: Halton/Faure M <= 126); paths
         of up to M + 3 segments. 29 as in Keller's tables: on the Cornell box (albedo up
         to 0.89) M = 6 left the image 0.8 % dark, 29 0.15 %
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
       - 4
       - SR >= 1 final-gather rays per eye ray. 4 measured best at equal time on the
         Cornell box (RMSE x sqrt(seconds) away from the light 0.0019, with 16: 0.0026,
         with 1: 0.0022; `path` 0.0032)
     * - share_neighbors
       - bool
       - false
       - average gather results with the 8 neighbouring pixels seeing the same triangle
     * - mirror_depth
       - int
       - 8
       - >= 0 delta bounces followed by eye and gather rays
     * - patch_size
       - float
       - scene diagonal / 24
       - > 0: the patch size h. Analytic shapes are divided into cells of about h x h,
         mesh triangles longer than sqrt(2) h into s x s similar sub-triangles (s <= 64),
         whatever the modelling. Radiance is constant per patch: a smaller h lowers the
         discretisation bias (``mi.cornell_box()``: -0.8 % at the default 0.144, -0.5 %
         at 0.08) and raises the patch count (memory, noise per patch)
     * - subdivide
       - bool
       - true
       - split long mesh triangles (above); false keeps the triangles as modelled (the
         papers' patches)
     * - hide_emitters
       - bool
       - false
       - do not show directly visible emitters

    Patches: the triangles of meshes (long ones split, see ``patch_size``), cells of
    ``rectangle``, ``disk``, ``sphere`` and ``cylinder`` (``mi_plugins.meshtable``; other
    shapes are refused by name). After a render, ``integrator.triangle_radiance`` (numpy (K, 2, 3): patch, side (0: the one its normal
    points to), RGB; L0 + reflected), ``reflected_radiance``, ``triangle_areas``,
    ``patch_shapes`` (shape id per patch), ``paths_used`` and ``delta_e_history`` hold the
    preprocessing result;
    ``integrator.preprocess(scene, seed)`` runs it alone. Radiosity setting: the matrix
    reports cases with non-diffuse BSDFs as not applicable.

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
        self.max_depth = p.int("max_depth", 29, lo=0)
        self.samples = p.int("samples", 100000, lo=1)
        self.epsilon = p.float("epsilon", None, lo=0, lo_open=True, note="optional: adaptive termination")
        self.batch = p.int("batch", 1000, lo=1)
        self.patience = p.int("patience", 2, lo=1)
        self.max_samples = p.int("max_samples", 10000000, lo=1)
        self.gather_samples = p.int("gather_samples", 4, lo=1)
        self.share_neighbors = p.bool("share_neighbors", False)
        self.mirror_depth = p.int("mirror_depth", 8, lo=0)
        self.patch_size, self.subdivide = patch_parameters(p)
        self.dims, limit = 2 * self.max_depth + 4, qmc.max_dim(self.sequence)   # lcg, independent: no limit
        if self.dims > limit:
            raise p.conflict(("max_depth", "sequence"), "max_depth <= %d with sequence '%s': max_depth=%d needs %d "
                             "dimensions; sequence '%s' has %d" % ((limit - 4) // 2, self.sequence, self.max_depth,
                                                                    self.dims, self.sequence, limit))
        self.triangle_radiance = self.reflected_radiance = self.triangle_areas = None
        self.paths_used, self.delta_e_history, self.particles = 0, [], None

    # ------------------------------------------------------------------ preprocessing
    def preprocess(self, scene, seed=0):
        """Run the particle phase; returns (triangle_radiance (K, 2, 3), triangle_areas (K,))."""
        self._particle_phase(scene, seed)
        return self.triangle_radiance, self.triangle_areas

    def _particle_phase(self, scene, seed):
        """The particle phase (or the one given to :meth:`use_particles`); keeps its numpy
        results and returns the patch table (never kept on the integrator: it holds the
        scene, which holds the integrator, a cycle that would keep every rendered scene alive)."""
        table = self.patch_table(scene)
        areas = table.areas_np
        self.delta_e_history = []
        if self.particles is not None:
            total, done = self.particles
            if total.shape != (table.count, 2, 3):
                raise ValueError("qmc_lighttrace: the given particle deposits have shape %s; this scene has %d "
                                 "patches, shape (%d, 2, 3)" % (total.shape, table.count, table.count))
        elif self.epsilon is None:   # fixed N: chunks of CHUNK paths (the estimate is the same)
            total, done = trace_range(self, scene, table, 0, self.samples, seed)[0], self.samples
        else:
            total, done = self._adaptive_phase(scene, table, seed)
        self.paths_used = done
        self.reflected_radiance = total / done / (np.pi * areas[:, None, None])
        self.triangle_radiance = self.reflected_radiance + self._triangle_emission(scene, table)
        self.triangle_areas = areas
        self.patch_shapes = np.array([shape.id() for shape in table.shapes])[table.shape_index_np]   # id per patch
        return table

    def _adaptive_phase(self, scene, table, seed):
        """Batches of ``batch`` paths until the patch radiances change by less than
        ``epsilon`` ``patience`` times in a row (or ``max_samples``): (deposits, paths)."""
        areas = table.areas_np
        total, emitted = np.zeros((table.count, 2, 3)), np.zeros(3)
        done, below, previous = 0, 0, None
        while done < self.max_samples:
            n = min(self.batch, self.max_samples - done)
            deposit, power = trace_range(self, scene, table, done, n, seed)
            total, emitted, done = total + deposit, emitted + power, done + n
            current = total / done / (np.pi * areas[:, None, None])
            norm = max(float(emitted.mean()) / done / np.pi, 1e-30)  # Phi / pi (= sum Le A of diffuse lights)
            if previous is not None:
                d = np.linalg.norm(current - previous, axis=2)
                delta_e = np.sqrt(np.sum(d * d * areas[:, None]) / np.sum(areas)) / norm
                self.delta_e_history.append(delta_e)
                below = below + 1 if delta_e < float(self.epsilon) else 0
                if below >= self.patience:
                    break
            previous = current
        return total, done

    def patch_table(self, scene):
        """The patches of ``scene`` (``patch_size``, ``subdivide``)."""
        return MeshTable(scene, "qmc_lighttrace", h=self.patch_size, subdivide=self.subdivide)

    def use_particles(self, deposits, paths):
        """Render with a particle phase traced elsewhere (e.g. summed over the ranges of a
        distributed render, :func:`mi_plugins.integrators.qmc_particles.trace_range`):
        ``deposits`` (K, 2, 3) reflected power per patch side of ``paths`` paths; None
        returns to tracing the phase in every render."""
        self.particles = None if deposits is None else (np.asarray(deposits, dtype=np.float64), int(paths))

    def _triangle_emission(self, scene, table):
        """Emitted radiance of each patch side (K, 2, 3), at its centroid along the normal."""
        si = table.surface_interaction(dr.arange(mi.UInt32, table.count), mi.Point2f(1.0 / 3.0, 1.0 / 3.0))
        emitter, sides = si.emitter(scene), []
        for z in (1.0, -1.0):
            si.wi = mi.Vector3f(0, 0, z)
            sides.append(np.array(emitter.eval(si, emitter != None), dtype=np.float64).T)  # noqa: E711
        return np.stack(sides, axis=1)

    # ------------------------------------------------------------------ rendering
    def render_frame(self, frame):
        scene = frame.scene
        table = self._particle_phase(scene, frame.seed)
        reflected = mi.Color3f(*(mi.Float(self.reflected_radiance[..., c].ravel()) for c in range(3)))
        frame.camera_passes(frame.spp, 1)
        cam = frame.camera_pass()
        rng = seeds.pcg(cam.count, frame.seed, "camera_path")
        path = specular_chain(scene, cam.ray, rng, max_bounces=self.mirror_depth, hide_emitters=self.hide_emitters)
        si = scene.ray_intersect(path.ray, path.reached)
        active = path.reached & si.is_valid()
        bsdf = si.bsdf(path.ray)
        # direct light: one light sample and one BSDF sample combined by multiple importance sampling
        # (a light sample alone has infinite variance where emitting surfaces meet, e.g. furnace edges)
        u = cam.sampler
        direct = direct_light(scene, si, bsdf, u.next_2d(), active, (u.next_1d(), u.next_2d()))
        gather = self._gather(scene, table, cam.sampler, rng, si, bsdf, active, reflected)
        if self.share_neighbors:
            gather = share_with_neighbours(gather, dr.select(active, patch_side(table, si), 0xFFFFFFFF), cam)
        frame.put_camera(cam, path.emission + path.throughput * (direct + gather))

    def _gather(self, scene, table, sampler, rng, si, bsdf, active, reflected):
        """SR cosine-distributed final-gather rays (on the side the eye ray arrived from)
        reading the reflected radiance L_k of the patch side they reach; a ray that reaches
        a purely specular surface follows it and takes the full radiance found behind it
        (its emission is not covered by the light sample)."""
        ctx = mi.BSDFContext()
        gather = dr.zeros(mi.Color3f, dr.width(si.p))
        for _ in range(self.gather_samples):  # SR gather rays (a small constant)
            d = mi.warp.square_to_cosine_hemisphere(sampler.next_2d())
            pdf = mi.warp.square_to_cosine_hemisphere_pdf(d)
            d.z = dr.mulsign(d.z, si.wi.z)  # the side the eye ray came from (twosided BSDFs)
            ok = active & (pdf > 0)
            weight = mi.Color3f(bsdf.eval(ctx, si, d, ok)) / dr.select(ok, pdf, 1.0)
            chain = specular_chain(scene, si.spawn_ray(si.to_world(d)), rng, max_bounces=self.mirror_depth)
            end = scene.ray_intersect(chain.ray, ok & chain.reached)
            hit = ok & chain.reached & end.is_valid()
            stored = dr.select(hit, dr.gather(mi.Color3f, reflected, patch_side(table, end), hit), 0.0)
            value = dr.select(ok & (chain.depth > 0), chain.emission + chain.throughput * stored, stored)
            gather += dr.select(ok, weight * value, 0.0)
        return gather / self.gather_samples

    def to_string(self):
        return "QMCLightTraceIntegrator[sequence=%s, max_depth=%d, samples=%d]" % (
            self.sequence, self.max_depth, self.samples)
