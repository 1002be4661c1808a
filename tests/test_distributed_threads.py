"""Multi-threaded Dask workers (Dask's default on multi-core nodes): a worker's tasks run
their Mitsuba work one at a time (mi_plugins.distributed.serial), so a two-thread worker
gives the single-thread worker's image; and a scene bundle written by many tasks and
processes at once appears whole (scene_bundle.materialize)."""
import os
import pickle
import subprocess
import sys
import tempfile
import threading
import time

import mitsuba as mi
import numpy as np
import pytest

pytest.importorskip("distributed")
from mi_plugins import distributed  # noqa: E402
from mi_plugins.distributed import dask_engine, plan, scene_bundle, serial  # noqa: E402

INTEGRATORS = {
    "path": '<integrator type="path"/>',
    "stochastic_ray": '<integrator type="stochastic_ray"><integer name="iterations" value="12"/></integrator>',
    "ray_bundle": '<integrator type="ray_bundle"><integer name="chains" value="8"/>'
                  '<integer name="iterations" value="12"/></integrator>',
    "qmc_lighttrace": '<integrator type="qmc_lighttrace"><integer name="samples" value="20000"/></integrator>',
}

#: quads (centre, u, v; normal u x v into the room) of the walls and the lamp
WALLS = {"floor": ((0, -1, 0), (0, 0, 1), (1, 0, 0)), "ceiling": ((0, 1, 0), (1, 0, 0), (0, 0, 1)),
         "back": ((0, 0, -1), (1, 0, 0), (0, 1, 0)), "left": ((-1, 0, 0), (0, 1, 0), (0, 0, 1)),
         "right": ((1, 0, 0), (0, 0, 1), (0, 1, 0)), "light": ((0, 0.99, 0), (0.23, 0, 0), (0, 0, 0.19))}
COLOURS = {"white": "0.725 0.71 0.68", "red": "0.63 0.065 0.05", "green": "0.14 0.45 0.091"}
SHAPES = {"floor": "white", "ceiling": "white", "back": "white", "left": "red", "right": "green", "box": "white"}


def write_obj(path, quads):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    corners = [np.asarray(c) + a * np.asarray(u) + b * np.asarray(v)
               for c, u, v in quads for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    with open(path, "w") as f:
        f.writelines("v %.6f %.6f %.6f\n" % tuple(p) for p in corners)
        f.writelines("f %d %d %d\nf %d %d %d\n" % (4 * k + 1, 4 * k + 2, 4 * k + 3, 4 * k + 1, 4 * k + 3, 4 * k + 4)
                     for k in range(len(quads)))


def cornell(directory, integrator):
    """A Cornell box laid out as mitsuba-data's cbox-rgb.xml: the main file (a ``res``
    default, the sensor, includes), fragments/bsdfs.xml and fragments/shapes.xml, whose
    obj meshes are named relative to the main file's folder."""
    for name, quad in WALLS.items():
        write_obj(os.path.join(directory, "meshes", name + ".obj"), [quad])
    centre, h = np.array([0.3, -0.7, 0.2]), 0.3      # a box standing on the floor: 5 faces facing out
    normals = [n for n in np.vstack([np.eye(3), -np.eye(3)]) if n[1] >= 0]
    faces = [(centre + h * n, h * np.roll(abs(n), 1), h * np.cross(n, np.roll(abs(n), 1))) for n in normals]
    write_obj(os.path.join(directory, "meshes", "box.obj"), faces)
    os.makedirs(os.path.join(directory, "fragments"), exist_ok=True)
    with open(os.path.join(directory, "fragments", "bsdfs.xml"), "w") as f:
        f.write('<scene version="3.0.0">%s</scene>\n' % "".join(
            '<bsdf type="diffuse" id="%s"><rgb name="reflectance" value="%s"/></bsdf>' % kv for kv in COLOURS.items()))
    with open(os.path.join(directory, "fragments", "shapes.xml"), "w") as f:
        f.write('<scene version="3.0.0">%s<shape type="obj" id="light"><string name="filename" '
                'value="meshes/light.obj"/><ref id="white"/><emitter type="area"><rgb name="radiance" '
                'value="18.4 14.0 6.75"/></emitter></shape></scene>\n' % "".join(
                    '<shape type="obj" id="%s"><string name="filename" value="meshes/%s.obj"/><ref id="%s"/>'
                    '</shape>' % (s, s, b) for s, b in SHAPES.items()))
    path = os.path.join(directory, "cbox-rgb.xml")
    with open(path, "w") as f:
        f.write('<scene version="3.0.0"><default name="res" value="256"/>%s<sensor type="perspective">'
                '<float name="fov" value="39.3"/><transform name="to_world"><lookat origin="0 0 3.9" target="0 0 0" '
                'up="0 1 0"/></transform><sampler type="independent"/><film type="hdrfilm"><integer name="width" '
                'value="$res"/><integer name="height" value="$res"/><rfilter type="box"/></film></sensor>'
                '<include filename="fragments/bsdfs.xml"/><include filename="fragments/shapes.xml"/></scene>\n'
                % integrator)
    return path


@pytest.fixture(scope="module")
def clients():
    """A worker of one Dask thread (the package's LocalCluster) and one of two (a user's
    LocalCluster, as Dask makes them on 2 cores); Dr.Jit uses both cores in each."""
    from distributed import Client, LocalCluster
    one = distributed.local_cluster(1)
    two = Client(LocalCluster(n_workers=1, threads_per_worker=2, processes=True, dashboard_address=":0"))
    for client in (one, two):                 # as a render does: the workers can then import the package
        dask_engine.set_variant_on(client, mi.variant())
    yield {1: one, 2: two}
    for client in (one, two):
        cluster = client.cluster
        client.close()
        cluster.close()


def worker_stats(client, reset=False):
    """serial.stats of the client's only worker."""
    return next(iter(client.run(serial.stats, reset=reset).values()))


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_a_two_thread_worker_gives_the_single_thread_image(name, clients, tmp_path):
    """The Cornell box of includes and obj meshes (res 16 as a $parameter), 4 tasks, on a
    worker of two Dask threads: both threads take tasks (one waited for the lock), never
    two task bodies at once, and the image is the one-thread worker's. Both run the same
    tasks (seeds fixed by the plan) on 2 Dr.Jit threads; what may differ is the order of
    atomic float additions (the film's splats; stochastic_ray's and ray_bundle's sums),
    so the tolerance is test_distributed's: 1e-5 relative (path, qmc_lighttrace), 1e-4
    (stochastic_ray, ray_bundle). Unserialised, these renders failed (a loop variable
    "presumed to be constant", "pointer is not registered", an OBJ file not found)."""
    path = cornell(str(tmp_path), INTEGRATORS[name])
    worker_stats(clients[2], reset=True)
    run = lambda n, seed=3: distributed.render(path, 8, client=clients[n], seed=seed, params={"res": "16"}, tasks=4,
                                                progress=False)
    two = run(2)
    stats = worker_stats(clients[2])
    one = run(1)
    assert two.tasks_done == one.tasks_done == 4 and np.all(np.isfinite(two.image)) and two.image.mean() > 0.05
    tolerance = 1e-5 if name in ("path", "qmc_lighttrace") else 1e-4
    np.testing.assert_allclose(two.image, one.image, rtol=tolerance, atol=1e-7)
    assert stats["peak"] == 1 and stats["waited"] >= 1 and stats["tasks"] == 4 + two.first_tasks + (
        two.first_tasks > 0), stats      # the two-phase renders' numbering task too
    if name == "path":                   # test of the test: another seed's image is far outside the tolerance
        assert not np.allclose(run(1, seed=4).image, one.image, rtol=1e-2, atol=1e-3)


def locked(on):
    """On a worker (by client.run): serial's lock, or a lock that never waits."""
    import threading
    import types
    from mi_plugins.distributed import serial
    serial.LOCK = threading.RLock() if on else types.SimpleNamespace(acquire=lambda blocking=True, timeout=-1: True,
                                                                     release=lambda: None)


def watched(on):
    """On a worker: serial's look for a cancelled task, or one that never finds it."""
    from mi_plugins.distributed import serial
    real = serial.__dict__.setdefault("_real_cancelled", serial._cancelled)
    serial._cancelled = real if on else (lambda: False)


def test_task_bodies_never_overlap_on_a_worker(clients):
    """Task bodies that sleep 0.2 s, 4 at once on the two-thread worker: one at a time,
    one of them waited; a body that raises frees the lock for the next; a body that
    calls another worker function (the lock is re-entrant) returns. Test of the test:
    with the lock replaced by a no-op on the worker, the detector sees two bodies at once."""
    client = clients[2]

    def nap(task):
        time.sleep(0.2)
        if task.kind == "fail":
            raise ValueError("the task's own error")
        return plan.worker_task(lambda: task.index)()

    body = plan.worker_task(nap)
    tasks = [plan.Task("pass", k) for k in range(4)]
    worker_stats(client, reset=True)
    found, _ = dask_engine.run_tasks(client, body, tasks, ((),), progress=False)
    stats = worker_stats(client, reset=True)
    assert found == {0: 0, 1: 1, 2: 2, 3: 3} and stats["tasks"] == 4 and stats["peak"] == 1 and stats["waited"] >= 1
    with pytest.raises(dask_engine.TaskFailed, match="own error"):
        dask_engine.run_tasks(client, body, [plan.Task("fail", 0)], ((),), progress=False)
    assert client.submit(body, plan.Task("pass", 5), pure=False).result(timeout=30) == 5
    try:
        client.run(locked, False)
        dask_engine.run_tasks(client, body, tasks, ((),), progress=False)
        assert worker_stats(client, reset=True)["peak"] == 2
    finally:
        client.run(locked, True)


def until(condition, seconds=30):
    deadline = time.perf_counter() + seconds
    while not condition():
        assert time.perf_counter() < deadline, "timed out"
        time.sleep(0.02)


def test_a_task_cancelled_while_it_waits_never_runs(clients):
    """Ctrl-C or a failed task cancels the render's other tasks; on a multi-threaded
    worker some of them wait for the lock: they give up instead of running (each could
    be a long render, after the render is over). Test of the test: a worker that does
    not look for the cancellation runs the cancelled body."""
    client = clients[2]

    def nap(task):
        time.sleep(task.spp / 10)
        return task.index
    body = plan.worker_task(nap)

    def bodies_run():
        worker_stats(client, reset=True)
        busy = client.submit(body, plan.Task("pass", 0, spp=8), pure=False)        # holds the lock 0.8 s
        until(lambda: worker_stats(client)["tasks"] == 1)
        waiting = client.submit(body, plan.Task("pass", 1, spp=1), pure=False)
        until(lambda: worker_stats(client)["waited"] == 1)
        client.cancel([waiting])
        assert busy.result(timeout=30) == 0
        time.sleep(0.1 + 4 * serial.POLL)          # time for the cancelled body to run, where it would
        return worker_stats(client, reset=True)["tasks"]
    try:
        assert bodies_run() == 1
        client.run(watched, False)
        assert bodies_run() == 2
    finally:
        client.run(watched, True)


def test_ctrl_c_on_a_two_thread_worker(clients, tmp_path, monkeypatch):
    """Ctrl-C after the first finished pass of a render on the two-thread worker: the
    finished pass is kept, and the next render on that worker runs every task (nothing
    of the interrupted one holds the lock)."""
    class Interrupting:
        def update(self, n):
            raise KeyboardInterrupt

        def close(self):
            pass
    path = cornell(str(tmp_path), INTEGRATORS["path"])
    run = lambda: distributed.render(path, 8, client=clients[2], seed=5, params={"res": "16"}, tasks=8)
    with monkeypatch.context() as patch:
        patch.setattr(dask_engine, "_bar", lambda total, desc, show: Interrupting())
        cut = run()
    assert cut.interrupted and cut.tasks_done == 1 and np.all(np.isfinite(cut.image))
    whole = run()
    assert not whole.interrupted and whole.tasks_done == 8


#: a process that writes the bundle pickled at argv[1] with argv[2] threads at time argv[3]
#: (scene_bundle.py loaded alone: no Mitsuba) and prints how many came back with every file whole
WRITER = """
import importlib.util, pickle, sys, threading, time
spec = importlib.util.spec_from_file_location("scene_bundle", sys.argv[4])
sb = importlib.util.module_from_spec(spec); spec.loader.exec_module(sb)
files, digest, folders = pickle.load(open(sys.argv[1], "rb"))
b = sb.SceneBundle("scene.xml", files, digest=digest, folders=folders)
whole = []
def write():
    time.sleep(max(0.0, float(sys.argv[3]) - time.time()))
    path = sb.materialize(b)
    root = path[:-len("scene.xml")]
    whole.append(all(open(root + n, "rb").read() == d for n, d in files.items()))
threads = [threading.Thread(target=write) for _ in range(int(sys.argv[2]))]
[t.start() for t in threads]; [t.join() for t in threads]
print(sum(whole))
"""


def write_at_once(b, threads, processes, tmp_path):
    """``threads`` threads of this process and ``processes`` processes of 4 threads write
    bundle ``b`` at the same moment, while a watcher reads every file as soon as it exists:
    (files seen torn by the watcher, callers of this process that came back with a file
    torn or missing, callers of the other processes that did, errors)."""
    root = os.path.join(tempfile.gettempdir(), "mi_plugins_scenes", b.digest)
    with open(tmp_path / "bundle.pickle", "wb") as f:
        pickle.dump((b.files, b.digest, b.folders), f)
    start = time.time() + (1.0 if processes else 0.05)          # the other processes' start-up
    others = [subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path / "bundle.pickle"), "4", str(start),
                                scene_bundle.__file__], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=dict(os.environ, TMPDIR=tempfile.gettempdir())) for _ in range(processes)]
    torn, returned, errors, done = [], [], [], threading.Event()

    def watch():
        while not done.is_set():
            for name, data in b.files.items():
                try:
                    with open(os.path.join(root, name), "rb") as f:
                        seen = f.read()
                except FileNotFoundError:
                    continue
                if seen != data:
                    torn.append(name)

    def write():
        time.sleep(max(0.0, start - time.time()))
        try:
            path = scene_bundle.materialize(b)
            returned.append(all(open(os.path.join(os.path.dirname(path), n), "rb").read() == d
                                for n, d in b.files.items()))
        except Exception as error:
            errors.append(error)
    watcher = threading.Thread(target=watch)
    watcher.start()
    writers = [threading.Thread(target=write) for _ in range(threads)]
    [t.start() for t in writers]
    [t.join() for t in writers]
    outputs = [p.communicate(timeout=60) for p in others]
    done.set()
    watcher.join()
    assert all(p.returncode == 0 for p in others), [err for _, err in outputs]
    return torn, returned.count(False), sum(4 - int(out) for out, _ in outputs), errors


def test_many_tasks_write_one_bundle_at_once(tmp_path, monkeypatch):
    """8 threads here and 2 processes of 4 threads write one bundle (4 files of 1 MB, an
    empty <path> folder) at once, as the tasks of multi-threaded workers on one machine
    do, while a watcher reads every file whenever it exists: no file is ever seen torn,
    every caller comes back with every file whole, none fails. Test of the test: a write
    that shows its file half-written for 20 ms is caught."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "worker"))
    os.makedirs(tmp_path / "worker")
    rng = np.random.default_rng(0)
    files = {"scene.xml": b"<scene/>", **{os.path.join("meshes", "m%d.obj" % k): rng.bytes(1 << 20)
                                          for k in range(4)}}
    b = scene_bundle.SceneBundle("scene.xml", files, digest="whole", folders=["empty"])
    torn, bad, bad_elsewhere, errors = write_at_once(b, 8, 2, tmp_path)
    assert (torn, bad, bad_elsewhere, errors) == ([], 0, 0, [])
    assert os.path.isdir(tmp_path / "worker" / "mi_plugins_scenes" / "whole" / "empty")

    def torn_write(path, data):
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "wb") as f:
            f.write(data[:len(data) // 2])
            f.flush()
            time.sleep(0.02)
            f.write(data[len(data) // 2:])
    monkeypatch.setattr(scene_bundle, "_write", torn_write)
    b = scene_bundle.SceneBundle("scene.xml", files, digest="torn", folders=[])
    torn, bad, _, errors = write_at_once(b, 8, 0, tmp_path)
    assert torn, (bad, errors)
