"""How a render splits into tasks and how their results merge: plain functions, no
engine (the Dask runner in :mod:`.dask_engine` only submits and collects them).

- Every integrator (Mitsuba's, ``stochastic_ray``, ``ray_bundle``): *passes*, pass k
  rendering ``spp_k`` samples with seed ``seed * SEED_STRIDE + k`` (fixed by the pass
  index, never by the worker): exactly the passes of
  :func:`mi_plugins.app.passes.render_in_passes` with ``passes = tasks``, merged by the same
  sample-weighted left fold in pass order, so the image is the single-process one.
- ``qmc_lighttrace``: first *particle* tasks, disjoint contiguous index ranges of one
  sequence (their union is the single-process point set), whose per-patch deposits are
  summed in range order; then *gather* passes as above, every one with that sum.
- ``ray_bundle`` with ``average_diffuse`` on purely diffuse scenes: first *chain* tasks
  (the chains split into groups, each with its own seed, through all iterations), whose
  per-patch average sums and counts are summed in task order; then *gathering* tasks
  (the final-gathering passes split into groups), merged by their pass counts
  (:mod:`mi_plugins.integrators.ray_bundle.split`). Other ``ray_bundle`` renders: passes.

The worker functions (:func:`run_pass`, :func:`run_particles`) take the shipped scene
(:mod:`.scene_bundle`) and keep the loaded scene per process for the next task.
"""
import functools
import gc
import hashlib
import pickle
from dataclasses import dataclass

import numpy as np

from mi_plugins.distributed import serial
from mi_plugins.render.phases import ChainGroups, ParticleRanges
from mi_plugins.render.pass_seeds import SEED_STRIDE, check_seed, split_spp
from mi_plugins.base.errors import root_cause

#: fewest chains of a ray_bundle chain group: a group runs every iteration's kernels, so
#: small groups repeat their launch and tracing cost (measured at 128 px: 16 groups of 4
#: chains took 2x one process's time on the same 2 cores)
MIN_CHAINS = 16

#: tasks of a render when not given: fixed, so that the image does not depend on the
#: number of workers (16 tasks keep up to 16 workers busy; more tasks, more overhead)
DEFAULT_TASKS = 16


@dataclass(frozen=True)
class Task:
    kind: str          # 'pass' (also qmc_lighttrace's gather passes), 'particles', 'chains', 'gathering',
    #                    'solve', 'view'
    index: int         # position in the merge order
    spp: int = 0       # pass: samples per pixel (its merge weight); chains: the render's spp;
    #                    gathering: final-gathering passes (its merge weight)
    seed: int = 0      # Mitsuba seed of the task's render; particles: the render seed
    start: int = 0     # particles: first path of the range; view: the sensor index
    count: int = 0     # particles: paths in the range; chains: chains of the group
    dark: tuple = None  # two-phase renders: the patches split in the dark, as one worker split
    #                    them (:func:`run_numbering`), replayed by every task

    def describe(self, total):
        if self.kind == "pass":
            return "pass %d of %d (%d spp, seed %d)" % (self.index + 1, total, self.spp, self.seed)
        if self.kind == "particles":
            return "particle range %d of %d (paths %d .. %d)" % (self.index + 1, total, self.start,
                                                                  self.start + self.count - 1)
        if self.kind == "chains":
            return "chain group %d of %d (%d chains, seed %d)" % (self.index + 1, total, self.count, self.seed)
        if self.kind == "solve":
            return "the solve (seed %d)" % self.seed
        if self.kind == "numbering":
            return "the patch numbering"
        if self.kind == "view":
            return "view %d of %d (sensor %d, %d spp, seed %d)" % (self.index + 1, total, self.start, self.spp,
                                                                   self.seed)
        return "gathering %d of %d (%d passes, seed %d)" % (self.index + 1, total, self.spp, self.seed)


@dataclass
class Phase:
    """One phase of a render: its ``tasks``, the worker function ``run`` (shipped scene,
    parameters, task, Dr.Jit threads[, the previous phase's merged result]) and, for a
    first phase, ``merge(results, tasks)``: what every task of the next phase receives."""
    name: str
    tasks: list
    run: object
    merge: object = None


def phases(integrator, scene, spp, tasks, seed):
    """The phases of a render of ``scene`` with ``spp`` samples in ``tasks`` tasks:
    (first phase or None, image phase, spp per unit of the image phase's merge weight).
    The integrator declares how it splits (``distributed_split(scene, spp)``: a
    :class:`~mi_plugins.render.phases.ParticleRanges` or
    :class:`~mi_plugins.render.phases.ChainGroups`; None, or an integrator without it:
    passes)."""
    split = getattr(integrator, "distributed_split", lambda scene, spp: None)(scene, spp)
    if isinstance(split, ParticleRanges):
        paths = split.paths
        first = Phase("particles", particle_tasks(paths, tasks, seed), run_particles,
                      lambda results, ranges: (merge_particles(results, ranges), paths, agreed(results)))
        return first, Phase("passes", pass_tasks(spp, tasks, seed), run_pass), 1.0
    if isinstance(split, ChainGroups):
        groups = min(tasks, max(1, split.chains // MIN_CHAINS))
        first = Phase("chains", chain_tasks(split.chains, spp, groups, seed), run_chains,
                      lambda results, groups: merge_chains(results, groups) + (agreed(results),))
        total = split.final_passes
        return first, Phase("gathering", gathering_tasks(total, tasks, seed), run_gathering), spp / max(total, 1)
    if split is not None:
        raise TypeError("%s.distributed_split returned %r: expected None, ParticleRanges or ChainGroups"
                        % (type(integrator).__name__, split))
    return None, Phase("passes", pass_tasks(spp, tasks, seed), run_pass), 1.0


def pass_tasks(spp, tasks, seed):
    """The passes of ``spp`` samples in at most ``tasks`` tasks (ValueError for a seed
    out of range)."""
    parts = split_spp(spp, tasks)
    check_seed(seed, len(parts))
    return [Task("pass", k, spp=part, seed=int(seed) * SEED_STRIDE + k) for k, part in enumerate(parts)]


def particle_tasks(samples, tasks, seed):
    """``samples`` paths in at most ``tasks`` contiguous ranges (sizes differ by at most one)."""
    sizes = split_spp(samples, tasks)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(int)
    return [Task("particles", k, seed=int(seed), start=int(s), count=int(n))
            for k, (s, n) in enumerate(zip(starts, sizes))]


def chain_tasks(chains, spp, tasks, seed):
    """``chains`` chains in at most ``tasks`` groups, each with its own render seed."""
    from mi_plugins.base import seeds
    return [Task("chains", k, spp=int(spp), seed=seeds.stream(seed, "tasks", k), count=n)
            for k, n in enumerate(split_spp(chains, tasks))]


def gathering_tasks(passes, tasks, seed):
    """``passes`` final-gathering passes in at most ``tasks`` groups (seeds as passes)."""
    parts = split_spp(passes, tasks)
    check_seed(seed, len(parts))
    return [Task("gathering", k, spp=n, seed=int(seed) * SEED_STRIDE + k) for k, n in enumerate(parts)]


def merge_sums(results, tasks):
    """Element-wise sum, in task order, of the tasks' tuples of arrays."""
    total = None
    for task in tasks:
        part = results[task.index]
        total = part if total is None else tuple(a + b for a, b in zip(total, part))
    return total


def merge_passes(results, tasks):
    """The sample-weighted mean of the finished passes ``results`` (index -> float64
    image), folded in pass order as :func:`mi_plugins.app.passes.render_in_passes` does;
    (image float32, spp of the finished passes), or (None, 0) when none finished."""
    accum, weight = None, 0
    for task in tasks:
        if task.index in results:
            part = results[task.index] * task.spp
            accum = part if accum is None else accum + part
            weight += task.spp
    return (None, 0) if accum is None else ((accum / weight).astype(np.float32), weight)


def merge_particles(results, tasks):
    """Sum of the ranges' deposits in range order (results: (deposits, patch numbering))."""
    return merge_sums({k: (v,) for k, v in check_order(results, tasks).items()}, tasks)[0]


def merge_chains(results, tasks):
    """Sums and counts of the chain groups added in task order (results: ((sums, counts),
    patch numbering))."""
    return merge_sums(check_order(results, tasks), tasks)


# ---------------------------------------------------------------------------- worker side
_LOADED = {}     # (bundle digest, parameters) -> scene, per worker process


def worker_task(fn):
    """A worker function run as every task runs: alone in its process, the garbage
    collector paused meanwhile and run at its end in the task's own thread
    (:func:`.serial.task`), an error sent back as :func:`_portable` makes it, raised after
    the collection without the original (whose traceback would keep the task's frames, and
    what they hold, alive)."""
    @functools.wraps(fn)
    def run(*args, **kwargs):
        with serial.task():
            try:
                return fn(*args, **kwargs)
            except Exception as error:
                failed = _portable(error)
        raise failed
    return run


def _scene(shipped, params, variant, threads):
    """The shipped scene, loaded once per worker process in the caller's ``variant``."""
    import drjit as dr
    import mitsuba as mi
    import mi_plugins
    if mi.variant() != variant:
        mi.set_variant(variant)
        mi_plugins.register()
    from mi_plugins.distributed.scene_bundle import materialize
    if threads:
        dr.set_thread_count(int(threads))
    key = (shipped.digest, tuple(sorted(params.items())))
    if key not in _LOADED:
        _LOADED.clear()                  # one scene per worker at a time: bounded memory
        gc.collect()                     # the last scene freed here, not while the next one traces
        # the shapes, hence the patches, in the file's order on every worker: sequential
        # loading, and no merging of meshes that share a BSDF (Mitsuba's optimisation
        # merges them in an order that differs from load to load; the first phase's
        # per-patch sums would then be added across different patches)
        _LOADED[key] = mi.load_file(materialize(shipped), parallel=False, optimize=False, **params)
    return _LOADED[key]


def shape_order(scene):
    """A fingerprint of ``scene``'s shapes in order: ids, primitive counts, bounds, and a
    mesh's vertex and face buffers (their order numbers the patches)."""
    import hashlib
    h = hashlib.sha1()
    for shape in scene.shapes():
        box = shape.bbox()
        h.update(repr((shape.id(), shape.primitive_count(), list(box.min), list(box.max))).encode())
        if hasattr(shape, "faces_buffer"):
            h.update(np.array(shape.vertex_positions_buffer()).tobytes())
            h.update(np.array(shape.faces_buffer()).tobytes())
    return h.hexdigest()[:16]


def check_order(results, tasks):
    """The first phase's results without their fingerprints; ValueError when workers
    numbered the patches differently."""
    orders = {results[t.index][1] for t in tasks}
    if len(orders) > 1:
        raise ValueError("distributed render: the workers numbered the patches differently (%d numberings: the "
                         "scene's shapes loaded in another order, or other patches split in the dark); the "
                         "per-patch sums cannot be added" % len(orders))
    return {t.index: results[t.index][0] for t in tasks}


def agreed(results):
    """The patch numbering the first phase's workers agreed on (:func:`check_order`)."""
    return next(iter(results.values()))[1]


def numbering(scene):
    """The numbering of the patches of ``scene``'s integrator: the shapes' order
    (:func:`shape_order`) and the patches split in the dark (``mi_plugins.patches.darkness``:
    a point where a ray grazes two touching surfaces may be judged otherwise by another
    process's acceleration structure)."""
    import json
    table = scene.integrator().patch_table(scene)
    return shape_order(scene) + " " + hashlib.sha1(json.dumps(table.dark_rounds).encode()).hexdigest()[:16]


@worker_task
def run_numbering(shipped, params, variant, task, threads=None):
    """The patches split in the dark by this worker's integrator (``darkness``: a tuple
    of rounds), which every task of a two-phase render replays: workers whose
    acceleration structures judge grazing rays otherwise (another build, another CPU)
    number the patches alike."""
    scene = _scene(shipped, params, variant, threads)
    return tuple(tuple(r) for r in _integrator(scene, task).patch_table(scene).dark_rounds)


def with_dark(tasks, rounds):
    """``tasks`` carrying the recorded dark splits ``rounds``."""
    import dataclasses
    return [dataclasses.replace(t, dark=rounds) for t in tasks]


def _integrator(scene, task):
    """``scene``'s integrator (kept by this process for the next task), replaying the
    task's recorded dark splits, or its own where the task carries none."""
    integrator = scene.integrator()
    if hasattr(integrator, "dark_record"):
        integrator.dark_record = task.dark
    return integrator


def _check_numbering(scene, expected):
    """ValueError where this worker numbers the patches otherwise than the first phase."""
    if numbering(scene) != expected:
        raise ValueError("distributed render: this worker numbers the patches otherwise than the workers of the "
                         "first phase (other patches split in the dark); the sums cannot be read here")


@worker_task
def run_pass(shipped, params, variant, task, threads=None, particles=None):
    """Render one pass; ``particles`` = (deposits, paths) for qmc_lighttrace's gather passes."""
    import mitsuba as mi
    scene = _scene(shipped, params, variant, threads)
    integrator = _integrator(scene, task)
    if particles is not None:
        _check_numbering(scene, particles[2])
        return np.array(integrator.render_with_particles(scene, particles[0], particles[1], task.spp, task.seed),
                        dtype=np.float64)
    return np.array(mi.render(scene, spp=task.spp, seed=task.seed), dtype=np.float64)


def _portable(error):
    """The exception to send back: mi.render wraps a Python integrator's exception in a
    Dr.Jit RuntimeError whose chain does not pickle; a fresh copy of the integrator's own
    (same type and message), or a RuntimeError naming it."""
    cause = root_cause(error)
    try:
        fresh = type(cause)(*cause.args)
        pickle.loads(pickle.dumps(fresh))
        return fresh
    except Exception:
        return RuntimeError("%s: %s" % (type(cause).__name__, cause))


@worker_task
def run_chains(shipped, params, variant, task, threads=None):
    """ray_bundle: the average sums and counts of one group of chains."""
    scene = _scene(shipped, params, variant, threads)
    return _integrator(scene, task).chain_averages(scene, task.seed, task.spp, task.count), numbering(scene)


@worker_task
def run_gathering(shipped, params, variant, task, threads=None, average=None):
    """ray_bundle: the image of one group of final-gathering passes from ``average``."""
    scene = _scene(shipped, params, variant, threads)
    integrator = _integrator(scene, task)
    _check_numbering(scene, average[2])
    return integrator.gather_from(scene, average[0], average[1], task.spp, task.seed)


@worker_task
def run_particles(shipped, params, variant, task, threads=None):
    """The deposits of one range of qmc_lighttrace's particle phase."""
    scene = _scene(shipped, params, variant, threads)
    return _integrator(scene, task).trace_particles(scene, task.start, task.count, task.seed), numbering(scene)


def keeps_solution(integrator):
    """The integrator displays one view-independent solution for every view (the package's
    finite-element integrators in a display mode, and qmc_lighttrace's particles)."""
    from mi_plugins.solution.integrator import SolutionIntegrator
    return isinstance(integrator, SolutionIntegrator) and (integrator.display != "gather"
                                                          or integrator.plugin == "qmc_lighttrace")


def view_tasks(sensors, spp, seed):
    """One task per sensor index, every one with the render seed (one solution for all)."""
    return [Task("view", k, spp=int(spp), seed=int(seed), start=int(s)) for k, s in enumerate(sensors)]


@worker_task
def run_solve(shipped, params, variant, task, threads=None):
    """The scene's solution, as the bytes of its file (shipped once to every view task)."""
    scene = _scene(shipped, params, variant, threads)
    return scene.integrator().solve(scene, task.seed).to_bytes()


@worker_task
def run_view(shipped, params, variant, task, threads=None, solution=None):
    """The image (float32) of one sensor, from the shipped ``solution`` where there is one."""
    import mitsuba as mi
    from mi_plugins.solution.solution import Solution
    scene = _scene(shipped, params, variant, threads)
    if solution is not None:
        scene.integrator().use_solution(Solution.from_bytes(solution, scene))
    return np.array(mi.render(scene, sensor=task.start, spp=task.spp, seed=task.seed), dtype=np.float32)
