"""``qmc_lighttrace``: Keller's quasi-Monte Carlo light tracing in the radiosity setting
(A. Keller, "A quasi-Monte Carlo algorithm for the global illumination problem in the
radiosity setting", 1994): a particle preprocess that deposits irradiance on the
purely diffuse patches (``qmc_particles``), then a render with direct light and final
gathering that continues paths across every other surface (``qmc_gather``). The user
reference is the class docstring.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.patches import darkness, refinement
from mi_plugins.base import sequences, seeds
from mi_plugins.base.param_docs import documented
from mi_plugins.render import checks
from mi_plugins.render.core import run_steps
from mi_plugins.render.frame import coverage
from mi_plugins.solution.display import edge_pixels, with_edges
from mi_plugins.solution.integrator import SolutionIntegrator, solution_meta
from mi_plugins.patches.neighbours import share_with_neighbours
from mi_plugins.integrators.qmc_lighttrace import parameters
from mi_plugins.integrators.qmc_lighttrace.checks import check_gather_lanes
from mi_plugins.solution.gather import CameraPaths, FlatTables
from mi_plugins.integrators.qmc_lighttrace.particles import dimensions, trace_range
from mi_plugins.integrators.qmc_lighttrace.phase import particle_phase
from mi_plugins.integrators.qmc_lighttrace.store import Layers
from mi_plugins.solution.surfaces import Surfaces
from mi_plugins.patches.build import cached_table, patch_parameters
from mi_plugins.patches.tessellation import default_patch_size
from mi_plugins.solution.solution import Solution
from mi_plugins.render.phases import ParticleRanges
from mi_plugins.base.params import Params

SEQUENCES = ("sobol", "halton", "faure", "lcg", "independent")
#: the particle index is 32-bit: at most this many paths (samples, batch, max_samples)
MAX_PATHS = 1 << 32
#: particle paths by default: the gather's (its noise is the camera side's), and at least
#: this in the display modes
DEFAULT_SAMPLES = 100000
#: the display modes' default paths per patch: their image reads the stored light of the
#: patches themselves, whose noise is the solve's (on a furnished room of 26 500 patches,
#: 100 000 paths left the smooth display at 2.2x the error of 1.6 M in the same seconds)
PATHS_PER_PATCH = 64
#: the display modes' default paths per camera sample of the render (spp x the film's
#: pixels) where that is more than PATHS_PER_PATCH per patch: the image's error is the
#: solve's noise and the camera samples' together, and only a solve that grows with the
#: camera samples lets it keep falling (on a furnished room, 128 x 96 px at 3721 spp:
#: 0.00185 RMSE with the patches' 1.7 M paths, 0.00115 with 13.7 M in 1.37x the time;
#: the time-optimal share measured there is 0.3 paths per camera sample: docs/qmc.md)
PATHS_PER_CAMERA_SAMPLE = 0.25
#: at most this many gather samples per eye ray
MAX_GATHER = 1024


@documented(parameters.ROWS)
class QMCLightTraceIntegrator(SolutionIntegrator):
    r"""
    .. _integrator-qmc_lighttrace:

    ``qmc_lighttrace`` (Keller 1994, quasi-Monte Carlo light tracing)
    -----------------------------------------------------------------

    Preprocess: N particle paths from the lights (surfaces, environment, delta lights),
    path i driven by point i of a (4 + 3M)-dimensional sequence (light choice and
    position, direction, then lobe and direction of each of the first M =
    ``sequence_depth`` bounces; later bounces pseudo-random with Russian roulette: paths
    are unbounded and unbiased). A particle deposits its irradiance on every *purely
    diffuse* patch side it hits (whose reflected radiance is the same in every direction),
    with the shading-normal factor |cos_sh| / |cos_geo|; other surfaces store nothing and
    scatter it on with any BSDF, weighted as Mitsuba's ``path`` weighs the same path.
    Deposits are kept per hit count (layers) in 64-bit fixed point (a seed gives the same
    deposits every time); optional adaptive termination (section 4: batches until the
    area-weighted change Delta E, relative to the emitted power / pi, stays below
    ``epsilon`` for ``patience`` batches).
    Render: eye rays from the sensor's sampler, through mirrors and glass to the visible
    point x; there emission + one light sample + SR BSDF gather samples, by multiple
    importance sampling. A gather sample reaching a purely diffuse y reads y's direct
    light (light and BSDF sample, MIS) plus the stored light of particle hits k >= 2,
    x rho(y) / pi; a non-diffuse y continues the path to the next diffuse surface.
    ``max_depth`` is Mitsuba's: every estimate holds exactly the paths of at most D
    segments. Eye rays are traced in passes of at most 2^22 gather lanes.

    .. pluginparameters::

    Particles and light samples take textured ``area`` lights uniformly on their shape
    (:mod:`mi_plugins.light.sources`). Patches: the triangles of meshes and the cells of
    ``rectangle``, ``disk``, ``sphere`` and ``cylinder``. **Refused before any work**, by
    name: other shapes, participating media, emitters that emit in one direction only
    (``directionalarea``: no light sample reaches them), and deposit layers x patches
    above 2^24 or half the available memory. After a render ``integrator.irradiance``
    (numpy (layers, K, 2, 3): hit-count layer, patch, side, RGB), ``triangle_areas``,
    ``patch_shapes``, ``paths_used`` and ``delta_e_history`` hold the preprocessing result;
    ``integrator.preprocess(scene, seed)`` runs it alone and also sets
    ``triangle_radiance`` (numpy (K, 2, 3)) and ``reflected_radiance``. Measurements behind
    the defaults: ``docs/qmc.md``.

    .. code-block:: python

        {'type': 'qmc_lighttrace', 'sequence': 'sobol', 'sequence_depth': 10, 'epsilon': 1e-3, 'gather_samples': 16}

    .. code-block:: xml

        <integrator type="qmc_lighttrace"><string name="sequence" value="faure"/>
            <integer name="max_depth" value="-1"/><integer name="samples" value="100000"/></integrator>
    """


    def __init__(self, props):
        super().__init__(props)
        p = Params(props, self.plugin)
        self.max_depth = p.int("max_depth", -1, lo=-1, note="-1: unbounded")
        self.sequence = p.choice("sequence", "sobol", SEQUENCES)
        self.scramble = p.bool("scramble", True)
        self.sequence_depth = p.int("sequence_depth", 3, lo=0)
        self.samples = p.int("samples", None, lo=1, hi=MAX_PATHS, note="optional: %d, in the display modes at "
                             "least %d per patch; the particle index is 32-bit" % (DEFAULT_SAMPLES, PATHS_PER_PATCH))
        self.epsilon = p.float("epsilon", None, lo=0, lo_open=True, note="optional: adaptive termination")
        self.batch = p.int("batch", 1000, lo=1, hi=MAX_PATHS)
        self.patience = p.int("patience", 2, lo=1)
        self.max_samples = p.int("max_samples", 10000000, lo=1, hi=MAX_PATHS, note="the particle index is 32-bit")
        self.gather_samples = p.int("gather_samples", None, lo=1, hi=MAX_GATHER,
                                    note="optional: 4 with display 'gather', 1 in the display modes")
        self.share_neighbors = p.bool("share_neighbors", False)
        self.mirror_depth = p.int("mirror_depth", -1, lo=-1, note="-1: as far as max_depth allows")
        self.patch_size, self.subdivide, self.cluster = patch_parameters(p)
        self.dark_levels = darkness.read_levels(p)
        self.dims, limit = dimensions(self.sequence_depth), sequences.max_dim(self.sequence)   # lcg, independent: no limit
        if self.dims > limit:
            raise p.conflict(("sequence_depth", "sequence"), "sequence_depth <= %d with sequence '%s': "
                             "sequence_depth=%d needs %d dimensions; sequence '%s' has %d"
                             % ((limit - 4) // 3, self.sequence, self.sequence_depth, self.dims, self.sequence, limit))
        self.refine, self.refine_threshold, self.min_patch_size, self.max_patches = refinement.read_parameters(p)
        if self.refine and self.epsilon is not None:
            raise p.conflict(("refine", "epsilon"), "refine=true with a fixed samples count (no epsilon: the "
                                                    "refinement follows the particle phase's fixed ranges)")
        self.refinements = []
        self.read_display(p)
        if self.gather_samples is None:      # (the display modes gather at every camera sample of a pixel)
            self.gather_samples = 4 if self.display == "gather" else 1
        if self.display != "gather" and self.share_neighbors:
            raise p.conflict(("share_neighbors", "display"), "share_neighbors=true with display='gather' only (it "
                                                             "averages the gather samples of neighbouring pixels)")
        if self.display == "baked" and self.max_depth >= 0:
            raise p.conflict(("display", "max_depth"), "display='baked' with max_depth=-1 (it shows the solution's "
                                                       "full radiance); display='smooth' reads any max_depth")
        self.layers = Layers(self.max_depth, visible=self.display != "gather")
        self.triangle_radiance = self.reflected_radiance = self.triangle_areas = self.irradiance = None
        self.paths_used, self.delta_e_history = 0, []
        self.camera_paths = 0      # the default solve's share of a render's camera samples (size_solve)

    def check_scene(self, scene, sensor):
        super().check_scene(scene, sensor)
        checks.refuse_shapes_without_patches(self.plugin, scene)
        checks.refuse_one_direction_emitters(self.plugin, scene)

    # ------------------------------------------------------------------ preprocessing
    def preprocess(self, scene, seed=0, report=True):
        """Run the particle phase alone (and with ``report`` evaluate the reported radiances);
        returns (triangle_radiance (K, 2, 3) or None, triangle_areas (K,))."""
        self.prepare(scene, None)
        table = self.patch_table(scene)
        self.size_solve(table, 0)
        particle_phase(self, scene, table, seed, report=report)
        return self.triangle_radiance, self.triangle_areas

    def solution_settings(self):
        return (self.sequence, self.scramble, self.sequence_depth, self.samples, self.epsilon, self.batch,
                self.patience, self.max_samples, self.max_depth, self.layers.max_hits, self.patch_size,
                self.subdivide, self.cluster, self.refine, self.refine_threshold, self.min_patch_size,
                self.max_patches, self.dark_levels)

    def compute_solution(self, scene, table, seed, preview=None, **unused):
        """The particle phase as a view-independent solution (read tables of particle hits
        k >= 2; the direct light is added per point or per patch by the display)."""
        def partial(tables, paths, done, total):
            at = refinement.replay(table, self.refinements)
            preview(Solution(tables, at.areas_np, self._meta(scene, at, seed, paths)), done, total, at)
        tables, error, refined = particle_phase(self, scene, table, seed, rendering=self.display == "gather",
                                                preview=partial if preview is not None else None)
        return Solution(tables, refined.areas_np, self._meta(scene, refined, seed, self.paths_used), error=error)

    def paths_for(self, table):
        """The particle paths of a solve on ``table``: ``samples``, or by default
        DEFAULT_SAMPLES with ``display`` 'gather'; in the display modes at least
        PATHS_PER_PATCH per patch of ``table`` and the render's share of its camera
        samples (:meth:`size_solve`)."""
        if self.samples is not None:
            return self.samples
        if self.display == "gather":
            return DEFAULT_SAMPLES
        return min(max(DEFAULT_SAMPLES, PATHS_PER_PATCH * int(table.front_count), self.camera_paths), MAX_PATHS)

    def size_solve(self, table, camera_samples):
        """Set the paths a display mode's default solve takes for a render of
        ``camera_samples`` (spp x the film's pixels): PATHS_PER_CAMERA_SAMPLE of them,
        rounded up to a multiple of an eighth of a power of two (renders of nearby budgets
        share one solve), where that is more than the patches' own share; else 0, and a
        render of any smaller budget reuses the same solve."""
        self.camera_paths = 0            # (paths_for then gives the patches' own share: the floor)
        self.camera_paths = self.budget_share(PATHS_PER_CAMERA_SAMPLE * camera_samples, self.paths_for(table),
                                              MAX_PATHS, self.samples is not None)

    def budget_key(self):
        return self.camera_paths

    def _meta(self, scene, table, seed, paths):
        return solution_meta(self, scene, table, seed, self.patch_size_for(scene), paths=int(paths),
                             sequence=self.sequence, refinements=list(self.refinements))

    def patch_size_for(self, scene):
        """``patch_size``, or by default the scene's diagonal / 24."""
        return self.patch_size if self.patch_size is not None else default_patch_size(scene)

    def patch_table(self, scene):
        """The patches of ``scene`` (``patch_size``, ``subdivide``; the dark splits of
        ``dark_record`` where one is given)."""
        table = cached_table(scene, self.plugin, self.patch_size_for(scene), subdivide=self.subdivide,
                             cluster=self.cluster, dark_levels=self.dark_levels)
        return darkness.with_splits(table, self.dark_record)     # (a distributed render's record)

    # ------------------------------------------------------------------ distributed parts
    def distributed_split(self, scene, spp):
        """A distributed render first traces disjoint ranges of the particle sequence
        (:meth:`trace_particles`), sums them, then renders passes with the sum
        (:meth:`render_with_particles`); adaptive termination is sequential: refused."""
        if self.epsilon is not None:
            raise ValueError("qmc_lighttrace: epsilon=%g (adaptive termination) is sequential and cannot be "
                             "split; valid for distributed rendering: no epsilon, a fixed samples count"
                             % self.epsilon)
        table = self.patch_table(scene)
        size = scene.sensors()[0].film().crop_size()
        self.size_solve(table, int(spp) * int(size[0]) * int(size[1]))
        return ParticleRanges(paths=self.paths_for(table))

    def trace_particles(self, scene, start, count, seed):
        """The deposits (layers, K, 2, 3) of the paths start .. start + count - 1."""
        return trace_range(self, scene, self.patch_table(scene), start, count, seed)[0]

    def render_with_particles(self, scene, deposits, paths, spp, seed):
        """The image of a render whose particle phase was traced elsewhere: ``deposits``
        (layers, K, 2, 3) of ``paths`` paths (e.g. summed over the ranges of a distributed
        render)."""
        return self.render_task(scene, (deposits, paths), spp=spp, seed=seed)

    # ------------------------------------------------------------------ rendering
    def render_frame(self, frame):
        scene = frame.scene
        per_pixel, passes = check_gather_lanes(self.plugin, frame, self.gather_samples)
        table = self.patch_table(scene)
        if frame.task is not None:         # a distributed render: the particles were traced elsewhere
            self.refinements = []
            solution = Solution(particle_phase(self, scene, table, frame.seed, given=frame.task)[0], table.areas_np,
                                self._meta(scene, table, frame.seed, self.paths_used))
        else:
            self.size_solve(table, frame.spp * frame.pixels)
            solution = self.solution_for(scene, frame.seed, table, frame.sensor)
            table = self.table_of(scene, solution)
        if self.display != "gather":
            return self.render_display(frame, solution, table)
        tables = solution.tables.reshape(-1, 3) if solution.tables.size else np.zeros((2, 3))   # (never width 1)
        stored = FlatTables(table, mi.Color3f(*(mi.Float(tables[:, c]) for c in range(3))))
        paths = CameraPaths(scene, table, Surfaces(scene, table), self.layers, stored, self.max_depth, self.mirror_depth,
                            self.hide_emitters)
        # passes of a bounded number of gather lanes (their memory: about 110 bytes each)
        frame.camera_passes(per_pixel, passes)
        edges = edge_pixels(frame, self.max_depth, self.hide_emitters, self.emitter_samples)
        def step(k):
            cam = frame.camera_pass()
            seed = frame.seed if k == 0 else seeds.stream(frame.seed, "gather pass", k)
            chain, si, light, gathered = paths.estimate(cam, seed, self.gather_samples)
            if self.share_neighbors:
                gathered = share_with_neighbours(gathered, paths.first_patch_side(si, si.is_valid()), cam)
            value = with_edges(frame, cam, chain, edges, chain.emission + chain.throughput * (light + gathered), seed)
            frame.put_camera(cam, value, coverage=coverage(scene, chain.surface, self.hide_emitters))

        run_steps(frame, None, step, stage=range(passes))

    def to_string(self):
        return "QMCLightTraceIntegrator[sequence=%s, max_depth=%d, sequence_depth=%d, samples=%s]" % (
            self.sequence, self.max_depth, self.sequence_depth, "auto" if self.samples is None else self.samples)
