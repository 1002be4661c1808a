"""The base class of the finite-element integrators (``ray_bundle``, ``qmc_lighttrace``):
view-independent solutions, kept and shown.

:class:`SolutionIntegrator` adds to :class:`~mi_plugins.render.core.CoreIntegrator`:

- the ``display`` parameter (``integrators.display``: 'gather', the integrator's own
  estimate, or 'smooth', 'patches', 'baked' from the solution) and ``preview_every``;
- the solution of the last scene and seed it rendered (:meth:`solution_for`): a render
  of the same scene (same object, same content: ``mi_plugins.base.fingerprint``) with the
  same seed and settings reuses it, whatever the sensor or spp, unless the plugin sizes
  its default solve by the render's camera samples (:meth:`size_solve`: then a render
  of a budget that asks for another size solves again; a solve of :meth:`solve` serves
  every budget); another seed, an edited scene or another scene object solves again
  (``solve_count`` counts the solves). The cache holds numpy arrays only, never the
  scene (which holds the integrator);
- :meth:`solve` (``mi_plugins.solve``), :meth:`use_solution` (a solution loaded from a
  file or shipped to a worker) and ``preview_callback`` (``f(image, done, total)``,
  called every ``preview_every`` steps of a solve with the image of the solution so far).

A plugin implements ``solution_settings()`` (every parameter its solution depends on)
and ``compute_solution(scene, table, seed, preview)``.
"""
import time

import mitsuba as mi
import numpy as np

from mi_plugins.base import collection, fingerprint, seeds
from mi_plugins.solution import display, steep
from mi_plugins.base.param_docs import Row
from mi_plugins.render.core import CoreIntegrator
from mi_plugins.render.frame import Frame


#: the display parameters of both finite-element integrators, read by ``read_display``
DISPLAY_ROWS = (
    Row("display", "string", "``'gather'``",
        "how the image is made: ``'gather'``, the integrator's own estimate (solved anew for every render); "
        "``'smooth'``, ``'patches'``, ``'baked'``: from the view-independent solution, kept for every later "
        "render of the scene with the same seed, whatever the sensor or spp (a default solve grows with the "
        "render's camera samples where they ask for more: ``qmc_lighttrace``'s ``samples``, ``ray_bundle``'s "
        "``iterations``). ``'smooth'``: direct light by next-event estimation plus the stored light "
        "interpolated from per-vertex values; ``'patches'``: the flat patch values; ``'baked'``: the "
        "interpolated patch radiance (``max_depth`` -1); glossy and specular visible points gather through to "
        "the next diffuse surface (``mi_plugins.solution.display``)"),
    Row("emitter_samples", "int", "8",
        "1 .. 64: camera rays per camera sample for the emission seen directly, in the pixels on a visible "
        "emitter's edge only, at the points of a rank-1 lattice across the pixel; 1: off"),
    Row("crowd_reach", "float", "1",
        ">= 0: the smooth display gathers (a light sample and a BSDF sample on to the next patch) instead of "
        "reading the stored light at the patches where other surfaces stand within this many of the patch's "
        "size (corners, junctions, shelves, contact lines: ``mi_plugins.patches.crowding``), where the light "
        "changes within a patch; 0: read at every patch"),
    Row("steep", "float", "0",
        ">= 0: the smooth display gathers instead of reading the stored light at the patches where its "
        "field departs at a corner from the patch's own value by more than this share of it (a lit strip "
        "beside a shadow; 0.5 measured), decided on a second solve with another seed, so a render solves "
        "twice (``mi_plugins.solution.steep``); not with ``refine``; 0: never"),
    Row("residual", "float", "0",
        "0 .. 1: the share of the display's camera samples at the points it reads that also gather and add "
        "the gather's difference from the reading, divided by the share: the image's expected value is then "
        "the gather's at every pixel (no reconstruction bias), with the gather's noise over the share "
        "(``mi_plugins.solution.display.with_residual``); a display mode only; 0: never"),
    Row("preview_every", "int", "0",
        ">= 0: with ``integrator.preview_callback = f(image, done, total)`` set, every N steps of a solve "
        "the image of the solution so far (one sample per pixel); 0: none"),
)


class SolutionIntegrator(CoreIntegrator):
    """See the module docstring."""

    def read_display(self, p):
        """Read ``display`` and ``preview_every`` with the plugin's reader ``p``."""
        self.display = p.choice("display", "gather", display.DISPLAYS)
        self.preview_every = p.int("preview_every", 0, lo=0, note="0: no previews")
        self.emitter_samples = p.int("emitter_samples", display.DEFAULT_EMITTER_SAMPLES, lo=1,
                                     hi=display.MAX_EMITTER_SAMPLES)
        self.crowd_reach = p.float("crowd_reach", display.DEFAULT_CROWD_REACH, lo=0,
                                   note="0: read the stored light at every patch")
        self.steep = p.float("steep", display.DEFAULT_STEEP, lo=0, note="0: never")
        if self.steep > 0 and getattr(self, "refine", False):
            raise p.conflict(("steep", "refine"), "steep > 0 with refine=false (the second solve that decides "
                             "the steep patches would split other patches), or steep=0")
        self.residual = p.float("residual", display.DEFAULT_RESIDUAL, lo=0, hi=1, note="0: never")
        if self.residual > 0 and self.display == "gather":
            raise p.conflict(("residual", "display"), "residual > 0 with a display mode of the solution "
                             "('smooth', 'patches', 'baked'), or residual=0")
        self.preview_callback = None
        self.solve_count = 0
        self._cached = None          # (key, Solution) of the last solve
        self._cached_any_budget = False  # it came from solve(): every render budget reuses it
        self._given = None           # a Solution handed over by use_solution
        self.last_solution = None    # the solution of the last render in a display mode (or solve)
        self.dark_record = None      # dark splits to replay (a distributed render's; None: its own)

    # ------------------------------------------------------------------ hooks
    def solution_settings(self):
        """Every parameter value the solution depends on (a tuple)."""
        raise NotImplementedError

    def compute_solution(self, scene, table, seed, preview=None, sensor=None, **solve):
        """Solve ``scene`` (patches ``table``) with ``seed``: a Solution;
        ``preview(solution_so_far, done, total[, patches])`` may be called along the way
        (``patches``: the table that solution is on, when refinement has split ``table``); ``sensor``:
        the sensor of the render that asks for it (None: the scene's first)."""
        raise NotImplementedError

    def patch_table(self, scene):
        """The patches of ``scene`` the solution is numbered by."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the cache
    def size_solve(self, table, camera_samples):
        """Size a default solve for a render of ``camera_samples`` (spp x the film's pixels;
        0: a solve alone); a plugin whose solve does not grow with them ignores it."""

    def budget_share(self, wanted, floor, cap, given):
        """The size of a default solve that a render's camera samples ask for: ``wanted``
        (paths, iterations) rounded up to a multiple of an eighth of a power of two, so that
        renders of nearby budgets share one solve, at most ``cap``; 0 (the solve's own
        default) where that is not above ``floor``, the size was ``given`` or the display
        is the gather."""
        wanted = int(wanted)
        if given or self.display == "gather" or wanted <= floor:
            return 0
        step = 1 << max(wanted.bit_length() - 4, 0)
        return min(-(-wanted // step) * step, cap)

    def budget_key(self):
        """What a render's budget changes in a default solve (a plugin whose solve grows
        with the camera samples: its size); never part of the settings a saved solution
        is matched by, which serves every budget."""
        return None

    def _key(self, scene, seed):
        return (id(scene), fingerprint.scene_fingerprint(scene), int(seed), self.solution_settings(),
                self.budget_key())

    def solution_for(self, scene, seed, table, sensor=None, **solve):
        """The solution of ``scene`` (patches ``table``) and ``seed``: the kept or given one
        where it matches, else a new solve (kept for the next render unless it was stopped
        early); ``solve``: further arguments of ``compute_solution``."""
        key = self._key(scene, seed)
        settings = list(map(repr, key[3]))
        given = self._given
        if given is not None and given.meta["fingerprint"] == key[1] and given.seed == int(seed) \
                and given.meta.get("settings_key") == settings:
            # (a scene of the same content loaded anew may list its shapes in another order)
            given = self._given = given.for_scene(scene)
            self.last_solution = given
            return given
        if self._cached is not None and (self._cached[0] == key or (self._cached_any_budget
                                                                   and self._cached[0][:-1] == key[:-1])):
            self.last_solution = self._cached[1]
            return self._cached[1]
        preview = self._previewer(scene, sensor, table) if self.preview_every and self.preview_callback else None
        start = time.perf_counter()
        solution = self.compute_solution(scene, table, int(seed), preview, sensor=sensor, **solve)
        solution.meta.update(seconds=time.perf_counter() - start, settings_key=settings)
        self.solve_count += 1
        if not self.progress.interrupted:
            self._cached, self._cached_any_budget = (key, solution), False
        self.last_solution = None if self.progress.interrupted else solution
        return solution

    def solve(self, scene, seed=0):
        """The view-independent solution of ``scene``, complete (geometry, direct light);
        no garbage collection meanwhile (:mod:`mi_plugins.base.collection`)."""
        with collection.paused():
            self.prepare(scene, None)
            table = self.patch_table(scene)
            self.size_solve(table, 0)
            solution = self.solution_for(scene, seed, table)
            # (a solve asked for serves the later renders of every budget, as a given one does)
            self._cached_any_budget = self._cached is not None and self._cached[1] is solution
            return solution.complete(scene, self.table_of(scene, solution))

    def table_of(self, scene, solution):
        """The patches ``solution`` is numbered by: its recorded dark splits (this process's
        own where they agree; a loaded solution's may differ: ``darkness.with_splits``)
        and its refinements."""
        from mi_plugins.patches import darkness, refinement
        table = darkness.with_splits(self.patch_table(scene), solution.meta.get("dark_splits"))
        return refinement.replay(table, solution.meta.get("refinements"))

    def use_solution(self, solution):
        """Render from ``solution`` (e.g. ``Solution.load(path, scene)``): every later render
        of a scene with its content, seed and settings uses it instead of solving; None
        forgets it."""
        self._given = solution

    # ------------------------------------------------------------------ display
    def steep_patches(self, frame, solution, table):
        """The steep patches of ``solution`` (:mod:`mi_plugins.solution.steep`), decided on
        a second solve of the same settings with another seed, so that which patches gather
        does not follow the displayed values' noise; kept with the solution. The second
        solve leaves the integrator's state as the first left it."""
        def decide():
            state = dict(self.__dict__)
            try:
                other = self.compute_solution(frame.scene, table, seeds.stream(solution.seed, "steep"), None,
                                              sensor=frame.sensor)
            finally:
                self.__dict__.clear()
                self.__dict__.update(state)
            other.field = solution.field
            return steep.steep_patches(other, table, self.steep)
        return solution.array("steep patches %r" % self.steep, decide)

    def render_display(self, frame, solution, table, steps=None):
        """The frame's image from ``solution`` in this integrator's display mode."""
        solution.complete(frame.scene, table)
        steep = self.steep_patches(frame, solution, table) if self.display == "smooth" and self.steep > 0 else None
        view = display.View(solution, table, self.display, self.crowd_reach, steep)
        display.render(frame, view, self.max_depth, getattr(self, "mirror_depth", -1), self.hide_emitters,
                       getattr(self, "gather_samples", 1), steps, self.emitter_samples, self.residual)

    def _previewer(self, scene, sensor, table):
        """``preview(solution, done, total, patches=table)``: the image (one camera sample per pixel) of the
        solution so far, in the display mode ('smooth' for 'gather'), handed to
        ``preview_callback(image, done, total)`` every ``preview_every`` steps."""
        sensor = sensor if sensor is not None else scene.sensors()[0]
        mode = self.display if self.display != "gather" else "smooth"
        last = [0]

        def preview(solution, done, total, patches=table):
            # ``patches``: the table the solution is on (a refined one, after splits)
            if last[0] < done < last[0] + self.preview_every and done < total:
                return                      # (a count that starts again, e.g. an extended burn-in, shows)
            last[0] = done
            frame = Frame(scene, sensor, 1, 0, self.plugin)
            solution.complete(scene, patches)
            display.render(frame, display.View(solution, patches, mode), self.max_depth, -1, self.hide_emitters, 1)
            self.preview_callback(mi.TensorXf(frame.develop()), done, total)
        return preview


def solution_meta(integ, scene, table, seed, patch_size, **extra):
    """The ``meta`` of a solution of ``integ`` (see mi_plugins.solution.solution)."""
    counts = np.bincount(table.shape_index_np[:table.front_count], minlength=len(table.shapes))
    shapes = [dict(id=shape.id(), digest=digest, patches=int(count), triangles=summary[1], **{"class": summary[0]})
              for shape, digest, count, summary in zip(table.shapes, fingerprint.shape_digests(scene), counts,
                                                       fingerprint.shape_summary(scene))]
    return dict(integrator=integ.plugin, seed=int(seed), max_depth=int(integ.max_depth), patch_size=float(patch_size),
                subdivide=bool(integ.subdivide), cluster=bool(integ.cluster), dark_levels=int(integ.dark_levels),
                dark_splits=list(table.dark_rounds),
                fingerprint=fingerprint.scene_fingerprint(scene), shapes=shapes, **extra)
