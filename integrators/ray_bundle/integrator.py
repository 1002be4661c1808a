"""The ``ray_bundle`` integrator: parameters and the iteration loop."""

import mitsuba as mi
import numpy as np

from mi_plugins.patches import gaps
from mi_plugins.base import caches, seeds
from mi_plugins.base.param_docs import documented
from mi_plugins.solution import display
from mi_plugins.render.core import MAX_ITERATIONS
from mi_plugins.render.frame import Frame
from mi_plugins.solution.integrator import SolutionIntegrator, solution_meta
from mi_plugins.patches import refinement
from mi_plugins.integrators.ray_bundle import checks, refine, split
from mi_plugins.integrators.ray_bundle.directions import SEQUENCES, DirectionStream
from mi_plugins.integrators.ray_bundle.estimators import ESTIMATORS
from mi_plugins.integrators.ray_bundle import frozen, parameters
from mi_plugins.integrators.ray_bundle import memory
from mi_plugins.integrators.ray_bundle.memory import available_memory
from mi_plugins.integrators.ray_bundle.run import Run, touch
from mi_plugins.patches import darkness
from mi_plugins.patches.build import cached_table, patch_parameters
from mi_plugins.patches.tessellation import default_patch_size
from mi_plugins.base.queries import scene_bounds
from mi_plugins.render.phases import ChainGroups
from mi_plugins.base.params import Params
from mi_plugins.solution.solution import Solution

#: the chains of the default (fewer where they would need over a quarter of the memory)
DEFAULT_CHAINS = 64
#: renders whose frozen steps are kept (one per scene and settings), for every ray_bundle
#: of the process together: a recording holds its scene's arrays, and a cache inside the
#: integrator, which its scene holds, would be a reference cycle through C++ that Python's
#: garbage collector cannot free. Only the last: a recording that keeps an earlier scene
#: alive keeps its plugins alive, and a frozen step whose calls would reach plugins not
#: among its inputs cannot be recorded (every later scene's render ran its ~150 kernels one
#: by one, 10x slower)
FROZEN_CACHE = 1
STEP_CACHE = frozen.StepCache(FROZEN_CACHE)
caches.register(STEP_CACHE.clear)
#: the paper's settings (sections 5-6): one chain of 128^2 lines, emission carried by the
#: bundles, the image from the chain's own patch values
PAPER_SETTINGS = {"chains": 1, "resolution": 128, "iterations": 64, "first_shot": False, "average_diffuse": False}
#: a display mode's default solve traces at least this many bundle lines per camera sample
#: of the render: with a fixed solve the display's error stops at the solve's noise. The
#: time-optimal share measured with the smooth display at 128 px is about 0.5 on a furnished
#: room and 0.12 on Mitsuba's Cornell box (docs/stochastic_iteration.md)
LINES_PER_CAMERA_SAMPLE = 0.25


@documented(parameters.ROWS)
class RayBundleIntegrator(SolutionIntegrator):
    r"""
    .. _integrator-ray_bundle:

    ``ray_bundle`` (stochastic iteration, global ray bundles)
    ---------------------------------------------------------

    Szirmay-Kalos, sections 5-6: finite-element stochastic iteration over the patches of
    the scene's surfaces. Each patch keeps its radiance in the current global direction
    w_m (and -w_m when ``bidirectional``). Each iteration transfers every patch's radiance
    along w_m with a bundle of ``resolution`` x ``resolution`` parallel lines across the
    scene (jittered every iteration; every line walks all its successive hits, and
    consecutive hits facing each other exchange radiance), picks a new random direction
    w_{m+1} and reflects: L_new[i] = Le_i(w_{m+1}) + 4 pi f_i(w_m, w_{m+1}) sum_j
    A(i,j,w_m) / A_i L[j] (2 pi per direction when bidirectional). The source term is
    evaluated where a line leaves a surface, the carried part at a fresh uniformly random
    point of each patch every iteration (unbiased patch averages). Many chains run in
    lockstep, one kernel per iteration, traced once and replayed (``dr.freeze``). Memory:
    O(chains x (patches + resolution^2)), every size checked before any work
    (:mod:`.memory`). The paper's settings: ``PAPER_SETTINGS``.

    .. pluginparameters::

    **``spp``:** ``mi.render(scene, spp=k)`` runs k x ``iterations`` global iterations of
    every chain (``burn_in`` once); every averaged iteration traces one camera sample per
    pixel and chain, from the sensor's sampler (with ``average_diffuse``, in the final
    gathering after the iterations). With a display from the solution, ``spp`` is the
    display's camera samples per pixel and the solve runs ``iterations`` global iterations
    (by default more where the camera samples ask for them: :meth:`size_solve`).
    **Scenes:** patches are the triangles of meshes and the cells of ``rectangle``,
    ``disk``, ``sphere`` and ``cylinder``; orientation is Mitsuba's (winding,
    ``flip_normals``); ``twosided`` surfaces have a patch per side. The environment lights
    the patches through the bundles; delta lights need ``first_shot``. Camera rays are
    followed through purely specular surfaces, and the delta lobe of a mixed BSDF is
    handed to Mitsuba's ``volpath`` (:mod:`mi_plugins.render.handoff`).
    **Refused before any work** (``Unsupported``, naming the plugin, the shape and what to
    use instead): participating media; BSDFs with a null lobe or that transmit, which the
    lines cannot cross; purely specular surfaces (see ``delta_surfaces``); shapes without
    patches; a lamp facing a surface that does not emit, closer than half the patch size
    (the light trapped in the gap would leave it as patch averages: :mod:`mi_plugins.patches.gaps`). The radiance carried is constant per patch: where it varies within a patch
    the result is the patch average (a smaller ``patch_size`` lowers that bias).
    Measurements behind the defaults: ``docs/stochastic_iteration.md``.

    .. code-block:: python

        {'type': 'ray_bundle', 'iterations': 128, 'resolution': 32, 'chains': 64, 'estimate': 'gather',
         'first_shot': True, 'average_diffuse': True}

    .. code-block:: xml

        <integrator type="ray_bundle"><integer name="iterations" value="128"/>
            <integer name="resolution" value="32"/><integer name="chains" value="64"/>
            <boolean name="first_shot" value="true"/><boolean name="average_diffuse" value="true"/>
            <string name="direction_sequence" value="independent"/></integrator>
    """
    iterative = True

    def __init__(self, props=mi.Properties()):
        super().__init__(props)
        p = Params(props, self.plugin)
        self.read_iterations(p, 16)
        self.iterations_given = p.given("iterations")
        self.camera_iterations = 0    # the default solve's share of a render's camera samples (size_solve)
        self.resolution = p.int("resolution", 32, lo=1)
        self.chains = p.int("chains", None, lo=1)       # None: DEFAULT_CHAINS, fewer to fit memory
        self.bidirectional = p.bool("bidirectional", True)
        self.first_shot = p.bool("first_shot", True)
        self.estimate = p.choice("estimate", "gather", tuple(ESTIMATORS))
        self.direction_sequence = p.choice("direction_sequence", "independent", SEQUENCES)
        independent = self.direction_sequence == "independent"
        self.stratify_chains = p.bool("stratify_chains", independent)
        if self.stratify_chains and not independent:
            raise p.conflict(("stratify_chains", "direction_sequence"),
                             "stratify_chains=true needs direction_sequence='independent' (the other sequences "
                             "give every chain its own sequence)")
        self.average_diffuse = p.bool("average_diffuse", True)
        self.share_diffuse = p.bool("share_diffuse", True)
        self.gather_nee = p.bool("gather_nee", True)
        self.patch_size, self.subdivide, self.cluster = patch_parameters(p)
        self.dark_levels = darkness.read_levels(p)
        self.max_depth = p.int("max_depth", -1, lo=-1, note="-1: unbounded")
        self.delta_surfaces = p.choice("delta_surfaces", "refuse", ("refuse", "camera_only"))
        self.adaptive = p.bool("adaptive", True)
        self.max_iterations = p.int("max_iterations", None, lo=1, hi=MAX_ITERATIONS,
                                    note="default: 8 x the render's planned iterations")
        self.point_sources = p.bool("point_sources", True)
        self.refine, self.refine_threshold, self.min_patch_size, self.max_patches = refinement.read_parameters(p)
        self.refinements = []
        self.read_display(p)
        if self.refine and self.display == "gather":
            raise p.conflict(("refine", "display"), "refine=true with display 'smooth', 'patches' or 'baked' (the "
                                                    "refined patches make the view-independent solution)")
        if self.display == "baked" and self.max_depth >= 0:
            raise p.conflict(("display", "max_depth"), "display='baked' with max_depth=-1 (it shows the solution's "
                                                       "full radiance); display='smooth' reads any max_depth")
        self.step_cache = STEP_CACHE      # the frozen steps of the last renders (shared, bounded)

    def orders(self):
        """Radiance values per lane: 1 (unbounded depth), else the bounce orders a path of
        ``max_depth`` segments can read from a patch (at least 1)."""
        if self.max_depth < 0:
            return 1
        return max(1, self.max_depth - (2 if self.first_shot else 1))

    def counts(self, spp):
        """(iterations, burn-in) of a render with ``spp``: ``iterations * spp`` and
        ``burn_in``, both raised where a finite depth needs a longer burn-in (every order
        present from the first averaged iteration)."""
        total, burn_in = max(self.iterations, self.camera_iterations) * int(spp), self.burn_in
        extra = max(0, self.orders() - 1 - burn_in) if self.max_depth >= 0 else 0
        return total + extra, burn_in + extra

    def iteration_count(self, spp):
        """Steps of a render with ``spp``: ``iterations * spp`` global iterations (each
        advances every chain), plus with ``average_diffuse`` the final gathering's passes
        (one per averaged iteration). An extended burn-in adds steps (see ``adaptive``).
        Other displays: ``iterations`` for the solve (none when it is kept), then the
        display's passes."""
        if self.display != "gather":
            return self.counts(1)[0] + display.pass_layout(int(spp), 1)[1]
        total, burn_in = self.counts(spp)
        return total + (total - burn_in if self.average_diffuse else 0)

    def patch_size_for(self, scene):
        """``patch_size``, or by default the scene's diagonal / 24 (``qmc_lighttrace``'s);
        with final gathering at least twice the bundle's line spacing (a patch narrower than
        the lines' spacing is missed by most bundles, and the gather only reads the patches
        after a bounce: noise only). A display from the solution shows the patches: there
        the finer patches' bias matters more than their noise (``cornell_closed``, 128 px,
        the smooth display: 0.52x -> 0.42x ``path``'s error at an equal second, the bias at
        128 iterations 0.0056 -> 0.0016)."""
        if self.patch_size is not None:
            return self.patch_size
        if self.display != "gather":
            return default_patch_size(scene)
        lo, hi = scene_bounds(scene)
        spacing = float(np.linalg.norm(hi - lo)) / self.resolution       # 2 x radius / resolution
        return max(default_patch_size(scene), 2.0 * spacing)

    def check_scene(self, scene, sensor):
        super().check_scene(scene, sensor)
        checks.check_scene(self.plugin, scene, self.delta_surfaces)
        checks.check_emitters(self.plugin, scene, self.first_shot)
        gaps.refuse_trapped_lights(self.plugin, scene, self.patch_size_for(scene))

    def render_frame(self, frame):
        self._guarded(self._render_frame, frame.rollback, frame)

    def _guarded(self, run, undo, *args):
        """``run(*args)`` with frozen steps, and where a step cannot be recorded ``undo()``
        and again with plain steps. (Every caller is inside a render or a solve, which pause
        the garbage collector, :mod:`mi_plugins.base.collection`: a Mitsuba object of an earlier
        scene freed between two frozen steps would change the instance registry that the
        steps recorded.)"""
        try:
            return run(*args)
        except frozen.FreezeFailed as error:
            self.step_cache.failed(error)      # this scene and these settings: plain steps
            undo()
            return run(*args)

    def patch_table(self, scene):
        """The patches of ``scene`` (checked against the memory first), with back sides;
        the dark splits of ``dark_record`` where one is given."""
        h = self.patch_size_for(scene)
        check = lambda: memory.check_patches(memory.predicted_patches(scene, h, self.subdivide, self.cluster),
                                             available_memory())
        table = cached_table(scene, self.plugin, h, back_sides=True, subdivide=self.subdivide, cluster=self.cluster,
                             before_build=check, dark_levels=self.dark_levels)
        return darkness.with_splits(table, self.dark_record)     # (a distributed render's record)

    def _render_frame(self, frame):
        table = self.patch_table(frame.scene)
        if self.display != "gather" and frame.task is None:
            self._render_solution(frame, table)
            return
        run = Run(self, frame, available_memory(), DEFAULT_CHAINS, table)
        task = frame.task              # a distributed render's part (split.py), or None
        if run.gather_only:          # a distributed render's gathering task: the averages are given
            run.average.load(*task.average)
            run.camera_passes(task.passes)
            touch(frame.camera_block("final"))
            run.final_gathering(self.steps(0, 0, task.passes), task.passes)
            return
        directions = DirectionStream(self.direction_sequence, run.layout.chains,
                                     seeds.numpy_rng(frame.seed, "directions"), self.stratify_chains,
                                     self.bidirectional, run.total + 1)
        steps = self.steps(run.total, run.burn_in, self.iteration_count(frame.spp))
        run.run(steps, directions)
        if task is not None:          # a distributed render's chain task: the averages, no image
            frame.result = run.average.numpy()
        elif run.average is not None and self.progress.averaged > 0:
            run.final_gathering(steps, self.progress.averaged)

    # ------------------------------------------------------------------ view-independent solutions
    def size_solve(self, table, camera_samples):
        """Set the global iterations a display mode's default solve runs for a render of
        ``camera_samples`` (spp x the film's pixels): LINES_PER_CAMERA_SAMPLE bundle lines
        each (``resolution``^2 lines per chain and iteration), rounded up as
        :meth:`budget_share` rounds, where that is more than ``iterations``; else 0."""
        lines = self.resolution ** 2 * (self.chains or DEFAULT_CHAINS)
        wanted = -(-int(LINES_PER_CAMERA_SAMPLE * camera_samples) // lines)
        self.camera_iterations = self.budget_share(wanted, self.iterations, MAX_ITERATIONS, self.iterations_given)

    def budget_key(self):
        return self.camera_iterations

    def solution_settings(self):
        return (self.iterations, self.burn_in, self.resolution, self.chains, self.bidirectional, self.first_shot,
                self.direction_sequence, self.stratify_chains, self.patch_size, self.subdivide, self.cluster,
                self.max_depth, self.adaptive, self.point_sources, self.refine, self.refine_threshold,
                self.min_patch_size, self.max_patches, self.share_diffuse, self.dark_levels)

    def _render_solution(self, frame, table):
        """A render in a display mode: the solution (kept, or solved now), then its display."""
        scene = frame.scene
        self.size_solve(table, frame.spp * frame.pixels)
        passes = display.pass_layout(frame.spp, frame.sample_pixels())[1]
        total, burn_in = self.counts(1)
        steps = self.steps(total, burn_in, total + passes)
        solution = self.solution_for(scene, frame.seed, table, frame.sensor, steps=steps)
        if self.progress.interrupted:
            return
        self.render_display(frame, solution, self.table_of(scene, solution), None if self.refine else steps)

    def compute_solution(self, scene, table, seed, preview=None, sensor=None, steps=None):
        """The bundles' irradiance per patch side, averaged over chains and the averaged
        iterations (``iterations``, whatever the spp: :mod:`.irradiance`)."""
        return self._guarded(self._compute_solution, lambda: None, scene, table, seed, preview, sensor, steps)

    def _compute_solution(self, scene, table, seed, preview, sensor, steps):
        frame = Frame(scene, sensor if sensor is not None else scene.sensors()[0], 1, seed, self.plugin)
        total, burn_in = self.counts(1)
        self.refinements = []
        pilot = (burn_in + max(1, int((total - burn_in) * refine.PILOT_SHARE)), burn_in) if self.refine else None
        run = Run(self, frame, available_memory(), DEFAULT_CHAINS, table, solve_only=True, children=self.refine,
                  counts=pilot)
        directions = DirectionStream(self.direction_sequence, run.layout.chains,
                                     seeds.numpy_rng(seed, "directions"), self.stratify_chains,
                                     self.bidirectional, run.total + total + 2)
        steps = steps if steps is not None and not self.refine else self.steps(run.total, run.burn_in)
        if preview is not None:
            # (the run is an argument, not in the closure: a run holding itself is a reference cycle)
            run.after = lambda r, done: preview(self._solution(r, scene, table, seed), done, r.total)
        run.run(steps, directions)
        split = refine.choose(self, run, scene, seed) if self.refine and not self.progress.interrupted else ()
        if len(split):                   # the solve goes on on the refined patches
            refined, origin, _ = refinement.refined(table, split)
            self.refinements = [split.tolist()]
            after = Run(self, frame, available_memory(), DEFAULT_CHAINS, refined, solve_only=True,
                        chains=run.layout.chains, counts=(refine.BURN_IN + total - burn_in, refine.BURN_IN))
            origin = refine.all_origins(table, refined, origin)
            refine.map_direct(run.transport.direct, after.transport.direct, origin)
            state = refine.map_state(run.state, run.layout, after.layout, origin)
            if preview is not None:
                after.after = lambda r, done: preview(self._solution(r, scene, refined, seed), done, r.total,
                                                      refined)
            after.run(self.steps(after.total, after.burn_in), directions, state=state)
            run, table = after, refined
        return self._solution(run, scene, table, seed)

    def _solution(self, run, scene, table, seed):
        tables, error = run.irradiance.numpy()
        meta = solution_meta(self, scene, table, seed, self.patch_size_for(scene), chains=run.layout.chains,
                             iterations=int(run.total + run.extended), averaged=int(self.progress.averaged),
                             refinements=list(self.refinements))
        return Solution(tables, table.areas_np[:table.front_count], meta, error=error,
                        direct_in_tables=not self.first_shot)

    # ------------------------------------------------------------------ distributed parts
    def distributed_split(self, scene, spp):
        """With ``average_diffuse`` on a purely diffuse scene a distributed render splits
        into groups of chains (:meth:`chain_averages`), whose per-patch averages are summed,
        then final-gathering passes from the sum (:meth:`gather_from`); otherwise into
        passes (see :mod:`.split`)."""
        if not split.splits_by_chains(self, scene):
            return None
        return ChainGroups(chains=self.chains or DEFAULT_CHAINS, final_passes=split.final_passes(self, spp))

    def chain_averages(self, scene, seed, spp, chains):
        """Sums (K, 3) and counts (K,) of the diffuse averages of ``chains`` chains."""
        return split.run_chains(self, scene, seed, spp, chains)

    def gather_from(self, scene, sums, counts, passes, seed):
        """The image (float64) of ``passes`` final-gathering passes from given averages."""
        return split.run_gathering(self, scene, sums, counts, passes, seed)

    def _averaged_radiance(self, state):
        """What the diffuse averages hold, per order: what the gathered point does not add
        itself (the reflected part R; with first_shot and gather_nee=false all of L but
        the emission, which then is the direct light). With a finite depth every order
        (the gathered point reads those it may)."""
        if self.max_depth >= 0:
            return state.L
        return [state.L[0]] if self.first_shot and not self.gather_nee else [state.R]
