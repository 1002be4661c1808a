"""Rendering across processes and machines on Dask: the same image whatever the number
of workers.

    from mi_plugins import distributed
    result = distributed.render("scene.xml", spp=256, seed=0)          # a LocalCluster, one worker per core
    result = distributed.render("scene.xml", spp=256, client=client)    # an existing cluster
    result.image                                                        # (H, W, 3) float32

The split and merge are engine-neutral plain functions (:mod:`.plan`); Dask only runs
them (:mod:`.dask_engine`). The scene file and every file it references by a relative
path are shipped with the tasks (:mod:`.scene_bundle`); files referenced by an absolute
path must be on a filesystem every worker sees. Dask is an optional dependency:
``pip install mi-plugins[distributed]``.
"""
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from mi_plugins.distributed import plan
from mi_plugins.distributed.scene_bundle import bundle

INSTALL = "distributed rendering needs Dask: pip install 'mi-plugins[distributed]' (dask[distributed])"


@dataclass
class DistributedResult:
    image: np.ndarray      # (H, W, C) float32, the merged finished passes (zeros when none finished)
    spp_done: int
    tasks_done: int        # passes merged into the image
    tasks: int             # passes planned
    seconds: float
    interrupted: bool
    workers: int
    first_tasks: int = 0       # tasks of a first phase: qmc_lighttrace's particle ranges, ray_bundle's chain groups


def require_dask():
    try:
        import distributed  # noqa: F401
    except ImportError as error:
        raise ImportError(INSTALL) from error


def local_cluster(workers, threads=None):
    """A LocalCluster of ``workers`` worker processes, one Dask thread each, and its client;
    Dr.Jit's threads per worker: ``threads``, by default the cores divided among the
    workers (at least 1; kept on the client for :func:`render`). The workers get
    ``MI_PLUGINS_VARIANT`` (this process's variant): they import the package when they
    unpickle their first task, before any code of theirs could set it."""
    require_dask()
    from distributed import Client, LocalCluster
    import mitsuba as mi
    cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True, dashboard_address=":0",
                           env={"MI_PLUGINS_VARIANT": mi.variant() or "llvm_ad_rgb"})
    client = Client(cluster)
    client.mi_plugins_threads = int(threads) if threads else max(1, (os.cpu_count() or 1) // int(workers))
    return client


@contextmanager
def connect(workers=None, scheduler=None):
    """A client of the Dask cluster at ``scheduler`` (an address), or else of a new
    :func:`local_cluster` of ``workers`` processes (default: one per core); closed on exit,
    with the local cluster."""
    require_dask()
    from distributed import Client
    client = Client(scheduler) if scheduler is not None else local_cluster(workers or os.cpu_count() or 1)
    try:
        yield client
    finally:
        cluster = client.cluster if scheduler is None else None
        client.close()
        if cluster is not None:
            cluster.close()


def render(scene_file, spp, *, client=None, seed=0, params=None, tasks=None, progress=True):
    """Render ``scene_file`` with ``spp`` samples per pixel in ``tasks`` tasks (default
    ``plan.DEFAULT_TASKS``; fixed, so the image does not depend on the workers) on
    ``client`` (default: a LocalCluster with one worker process per core, closed at the
    end). ``params``: the scene's XML ``$parameters``. Returns a :class:`DistributedResult`."""
    import mitsuba as mi
    require_dask()
    params = {k: str(v) for k, v in (params or {}).items()}
    tasks = plan.DEFAULT_TASKS if tasks is None else int(tasks)
    if int(spp) < 1 or tasks < 1:
        raise ValueError("spp=%s, tasks=%s: valid range: 1 or more each" % (spp, tasks))
    scene = mi.load_file(scene_file, **params)      # errors of the scene surface here, before any task
    if scene.integrator() is None:
        raise ValueError("scene '%s' has no integrator" % scene_file)
    shipped = bundle(scene_file, params)

    def on(client):
        workers = max(len(client.scheduler_info().get("workers", {})), 1)
        threads = getattr(client, "mi_plugins_threads", None)    # None: Dr.Jit's default on each worker
        return _render(client, scene, shipped, params, int(spp), int(seed), tasks, threads, progress, workers)
    if client is not None:
        return on(client)
    with connect() as own:
        return on(own)


def _render(client, scene, shipped, params, spp, seed, tasks, threads, progress, workers):
    """The phases of :func:`mi_plugins.distributed.plan.phases` on ``client``: the first
    (if any) merged and broadcast to every task of the image phase."""
    from mi_plugins.distributed.dask_engine import Shipped, run_tasks
    t0 = time.perf_counter()
    first, image_phase, spp_per_weight = plan.phases(scene.integrator(), scene, spp, tasks, seed)
    import mitsuba as mi
    from mi_plugins.distributed.dask_engine import set_variant_on
    variant = mi.variant()
    set_variant_on(client, variant)             # before any task: the workers import the package to unpickle one
    remote = Shipped(client, shipped)
    shared = None
    if first is not None:
        # one worker's dark splits, replayed by every task: the per-patch sums add up
        rounds = run_tasks(client, plan.run_numbering, [plan.Task("numbering", 0)], ((remote, params, variant),
                                                                                    threads), False)[0][0]
        first.tasks, image_phase.tasks = plan.with_dark(first.tasks, rounds), plan.with_dark(image_phase.tasks, rounds)
        found, stopped = run_tasks(client, first.run, first.tasks, ((remote, params, variant), threads), progress,
                                   first.name)
        if stopped:
            raise KeyboardInterrupt          # nothing of the image is made yet
        shared = Shipped(client, first.merge(found, first.tasks))
    found, stopped = run_tasks(client, image_phase.run, image_phase.tasks, ((remote, params, variant), threads, shared),
                               progress, image_phase.name)
    image, weight = plan.merge_passes(found, image_phase.tasks)
    if image is None:
        size = scene.sensors()[0].film().crop_size()
        image = np.zeros((size[1], size[0], 3), dtype=np.float32)
    return DistributedResult(image, int(round(weight * spp_per_weight)), len(found), len(image_phase.tasks),
                             time.perf_counter() - t0, stopped, workers, len(first.tasks) if first else 0)


@dataclass
class ViewsResult:
    images: list           # (H, W, C) float32 per sensor, in the order asked for
    sensors: list          # the sensor indices
    seconds: float
    interrupted: bool
    workers: int
    solves: int            # 1 where one solution serves every view, else 0


def render_views(scene_file, spp, *, sensors="all", client=None, seed=0, params=None, progress=True):
    """Render the sensors ``sensors`` ('all' or indices) of ``scene_file``, one task per
    sensor on ``client`` (as :func:`render`). A finite-element integrator that keeps its
    solution (``plan.keeps_solution``) solves once, in a task of its own; the solution is
    shipped once to every worker and every view displays it. Returns a :class:`ViewsResult`."""
    import mitsuba as mi
    require_dask()
    params = {k: str(v) for k, v in (params or {}).items()}
    scene = mi.load_file(scene_file, **params)
    if scene.integrator() is None:
        raise ValueError("scene '%s' has no integrator" % scene_file)
    from mi_plugins.solution.views import sensor_list
    sensors = list(range(len(scene.sensors()))) if sensors == "all" else [int(k) for k in sensors]
    sensor_list(scene, sensors)                       # a bad index is refused before any task
    if int(spp) < 1:
        raise ValueError("spp=%s: valid range: 1 or more" % spp)
    shipped = bundle(scene_file, params)
    keeps = plan.keeps_solution(scene.integrator())

    def on(client):
        from mi_plugins.distributed.dask_engine import Shipped, run_tasks, set_variant_on
        t0 = time.perf_counter()
        workers = max(len(client.scheduler_info().get("workers", {})), 1)
        threads = getattr(client, "mi_plugins_threads", None)
        variant = mi.variant()
        set_variant_on(client, variant)
        remote = Shipped(client, shipped)
        shared = None
        if keeps:
            found, stopped = run_tasks(client, plan.run_solve, [plan.Task("solve", 0, seed=int(seed))],
                                       ((remote, params, variant), threads), progress, "solve")
            if stopped:
                raise KeyboardInterrupt
            shared = Shipped(client, found[0])
        tasks = plan.view_tasks(sensors, spp, seed)
        found, stopped = run_tasks(client, plan.run_view, tasks, ((remote, params, variant), threads, shared),
                                   progress, "views")
        images = [found[t.index] for t in tasks if t.index in found]
        return ViewsResult(images, [t.start for t in tasks if t.index in found], time.perf_counter() - t0, stopped,
                           workers, int(keeps))
    if client is not None:
        return on(client)
    with connect() as own:
        return on(own)
