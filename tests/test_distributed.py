"""Distributed rendering on Dask (mi_plugins.distributed): the image does not depend on
the number of workers, it equals the single-process passes where those are
deterministic, a killed worker loses nothing, a failing task stops the render clearly,
the scene and its files are shipped with the tasks."""
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time

import mitsuba as mi
import numpy as np
import pytest

from conftest import REPO

pytest.importorskip("distributed")
from mi_plugins import distributed
from mi_plugins.app import exr, passes
from mi_plugins.distributed import dask_engine, plan, scene_bundle  # noqa: E402

KELLER = os.path.join(REPO, "configs", "keller_cube.xml")   # L = 0.5 everywhere, 32 x 32 px
INTEGRATORS = {
    "path": '<integrator type="path"/>',
    "stochastic_ray": '<integrator type="stochastic_ray"><integer name="iterations" value="12"/></integrator>',
    "ray_bundle": '<integrator type="ray_bundle"><integer name="chains" value="8"/>'
                  '<integer name="iterations" value="12"/></integrator>',
    "qmc_lighttrace": '<integrator type="qmc_lighttrace"><integer name="samples" value="30000"/>'
                      '<integer name="max_depth" value="12"/></integrator>',
}


def scene_copy(directory, integrator, extra="", source=KELLER):
    """A configs/ scene (default keller_cube.xml) with ``integrator`` in ``directory``
    (its meshes next to it, relative)."""
    text = open(source).read()
    text = re.sub(r'<integrator type="\$integrator">\s*</integrator>', integrator + extra, text)
    os.makedirs(os.path.join(directory, "meshes"), exist_ok=True)
    for mesh in re.findall(r'value="(meshes/[^"]+)"', text):
        shutil.copy(os.path.join(REPO, "configs", mesh), os.path.join(directory, mesh))
    path = os.path.join(directory, "scene.xml")
    with open(path, "w") as f:
        f.write(text)
    return path


@pytest.fixture(scope="module")
def clients():
    """LocalClusters of 1, 2 and 3 worker processes (started once for the module)."""
    made = {n: distributed.local_cluster(n) for n in (1, 2, 3)}
    yield made
    for client in made.values():
        cluster = client.cluster
        client.close()
        cluster.close()


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenes")
    return {name: scene_copy(str(root / name), xml) for name, xml in INTEGRATORS.items()}


@pytest.mark.parametrize("name", sorted(INTEGRATORS))
def test_the_image_does_not_depend_on_the_number_of_workers(name, clients, scenes):
    """1, 2 and 3 workers, the same seed and tasks: the same image up to the order of
    float additions. Every task computes the same numbers whichever worker runs it, but
    the film's splats are atomic float adds whose order follows the thread schedule (1
    worker runs 2 Dr.Jit threads, 2 workers 1 each): `path` and `qmc_lighttrace` (exact
    integer particle sums) differ only there, allowed 1e-5 relative; `stochastic_ray` and
    `ray_bundle` also add floats with atomics inside a render (`ray_bundle` measured 9e-8
    absolute, 1.8e-7 relative between 1 and 2 workers), allowed 1e-4. Every image is
    the exact 0.5 of Keller's cube to its noise."""
    images = [distributed.render(scenes[name], 4, client=clients[n], seed=5, tasks=4, progress=False).image
              for n in (1, 2, 3)]
    for image in images[1:]:
        tolerance = 1e-5 if name in ("path", "qmc_lighttrace") else 1e-4
        np.testing.assert_allclose(image, images[0], rtol=tolerance, atol=1e-7)
    assert abs(images[0].mean() - 0.5) < 0.01, images[0].mean()


@pytest.mark.parametrize("name", ["qmc_lighttrace", "ray_bundle"])
def test_several_shapes_keep_their_patches_on_every_worker(name, clients, tmp_path):
    """The Bekaert box (two meshes, L = 1): the first phase's per-patch sums come from
    workers that loaded the scene separately; they number the patches alike (sequential
    loading), so 1 and 2 workers agree (up to the film's float splats for
    qmc_lighttrace) and the image is exact. Test of the test: results carrying two patch numberings are refused."""
    path = scene_copy(str(tmp_path), INTEGRATORS[name], source=os.path.join(REPO, "configs", "bekaert_box.xml"))
    one, two = (distributed.render(path, 2, client=clients[n], seed=3, tasks=4, progress=False).image
                for n in (1, 2))
    # patches mixed up between workers moved the mean by 0.6 % (before sequential loading)
    np.testing.assert_allclose(one, two, rtol=1e-5 if name == "qmc_lighttrace" else 1e-4, atol=1e-7)
    assert abs(one.mean() - 1.0) < 0.03, one.mean()
    tasks = plan.particle_tasks(10, 2, 0)
    with pytest.raises(ValueError, match="numbered the patches differently"):
        plan.merge_particles({0: (np.zeros(3), "a"), 1: (np.zeros(3), "b")}, tasks)
    # a second-phase worker that numbers the patches otherwise (other dark splits) refuses too
    scene = mi.load_file(path)
    plan._check_numbering(scene, plan.numbering(scene))
    with pytest.raises(ValueError, match="numbers the patches otherwise"):
        plan._check_numbering(scene, plan.numbering(scene) + "x")


def test_every_task_replays_one_workers_dark_splits(monkeypatch, tmp_path):
    """A worker whose rays judge grazing points otherwise (another acceleration structure)
    splits other patches in the dark: the render's numbering task records one worker's
    splits and every task replays them, so that the per-patch sums add up. Here this
    process plays both: its splits with a judgement that finds 3 patches half dark each
    round are recorded, and a plain load replays them. Test of the test: a task without
    the record numbers the patches as its own process does."""
    from mi_plugins.patches import darkness
    path = scene_copy(str(tmp_path), INTEGRATORS["qmc_lighttrace"])
    shipped = distributed.bundle(path, {})

    def fractions(table, *args, **kwargs):
        f = np.zeros((table.front_count, 2))
        f[:3, 0] = 0.5
        return f
    with monkeypatch.context() as patch:
        patch.setattr(darkness, "dark_fractions", fractions)
        record = plan.run_numbering(shipped, {}, mi.variant(), plan.Task("numbering", 0))
        other = mi.load_file(path)
        expected = plan.numbering(other)
    assert len(record) == darkness.DEFAULT_LEVELS and all(len(r) == 3 for r in record)
    plain = mi.load_file(path)
    own = plan.numbering(plain)
    assert own != expected
    task = plan.with_dark([plan.Task("particles", 0, seed=0, start=0, count=100)], record)[0]
    plan._integrator(plain, task)
    assert plan.numbering(plain) == expected
    assert plain.integrator().patch_table(plain).dark_rounds == [list(r) for r in record]
    plan._integrator(plain, plan.Task("particles", 0, seed=0, start=0, count=100))
    assert plan.numbering(plain) == own


def test_passes_equal_the_single_process_render(clients, scenes):
    """The split is render_in_passes' split: with tasks = passes and the same seed the
    image is the same, bit for bit (`path`)."""
    scene = mi.load_file(scenes["path"])
    single = passes.render_in_passes(scene, spp=6, passes=3, seed=2).image
    shared = distributed.render(scenes["path"], 6, client=clients[2], seed=2, tasks=3, progress=False)
    assert np.array_equal(single, shared.image) and shared.spp_done == 6 and shared.tasks_done == 3
    for _ in range(3):   # back to back on one client: each render ships its own copy of the scene
        again = distributed.render(scenes["path"], 6, client=clients[2], seed=2, tasks=3, progress=False)
        assert np.array_equal(again.image, single)


def test_particle_ranges_are_the_single_process_point_set(clients, scenes):
    """qmc_lighttrace's particle phase split into 3 ranges: the deposits equal one
    single-process trace of all paths up to the fixed-point rounding of each range
    (relative 1e-6); the gather then uses the sum. Test of the test: ranges that skip
    one path differ."""
    from mi_plugins.integrators.qmc_lighttrace.particles import trace_range
    scene = mi.load_file(scenes["qmc_lighttrace"])
    integ = scene.integrator()
    table = integ.patch_table(scene)
    whole = trace_range(integ, scene, table, 0, 30000, 7)[0]
    ranges = plan.particle_tasks(30000, 3, 7)
    assert [(t.start, t.count) for t in ranges] == [(0, 10000), (10000, 10000), (20000, 10000)]
    parts = {t.index: (trace_range(integ, scene, table, t.start, t.count, 7)[0], "order") for t in ranges}
    np.testing.assert_allclose(plan.merge_particles(parts, ranges), whole, rtol=1e-6, atol=1e-9 * whole.max())
    parts[1] = (trace_range(integ, scene, table, 10001, 9999, 7)[0], "order")
    assert not np.allclose(plan.merge_particles(parts, ranges), whole, rtol=1e-4)


def test_ray_bundle_splits_its_chains_and_its_final_gathering(clients, scenes, tmp_path):
    """ray_bundle (defaults: average_diffuse) on a diffuse scene: chain groups whose
    average sums and counts are added, then gathering groups; exact to its noise. Test of
    the test: a merge that keeps only the first group's sums but all counts loses 3/4 of
    the averaged (reflected) radiance: 0.4525.
    Without average_diffuse the render is split into passes."""
    from mi_plugins.integrators.ray_bundle import split
    res = distributed.render(scenes["ray_bundle"], 2, client=clients[2], seed=1, tasks=4, progress=False)
    assert res.first_tasks == 1 and res.tasks == 4 and res.spp_done == 2    # 8 chains: one group of >= 16
    assert abs(res.image.mean() - 0.5) < 0.01, res.image.mean()
    scene = mi.load_file(scenes["ray_bundle"])
    integ = scene.integrator()
    groups = plan.chain_tasks(8, 2, 4, 1)
    parts = {t.index: split.run_chains(integ, scene, t.seed, t.spp, t.count) for t in groups}
    sums, counts = plan.merge_sums(parts, groups)
    right = split.run_gathering(integ, scene, sums, counts, 8, 5)
    wrong = split.run_gathering(integ, scene, parts[0][0], counts, 8, 5)
    direct = np.array(mi.render(scene, spp=1, seed=5))      # reference scale: a whole render
    assert abs(right.mean() - 0.5) < 0.01 and abs(direct.mean() - 0.5) < 0.01
    assert wrong.mean() < right.mean() - 0.03, (wrong.mean(), right.mean())     # measured 0.4525
    plain = scene_copy(str(tmp_path), '<integrator type="ray_bundle"><integer name="chains" value="8"/>'
                       '<boolean name="average_diffuse" value="false"/><integer name="iterations" value="12"/>'
                       '</integrator>')
    res = distributed.render(plain, 2, client=clients[2], seed=1, tasks=2, progress=False)
    assert res.first_tasks == 0 and res.tasks == 2 and abs(res.image.mean() - 0.5) < 0.02


def kill_soon(pid, delay=0.3):
    """SIGKILL process ``pid`` after ``delay`` s (in a thread); the event is set once killed."""
    killed = threading.Event()

    def kill():
        time.sleep(delay)
        os.kill(pid, signal.SIGKILL)
        killed.set()
    threading.Thread(target=kill, daemon=True).start()
    return killed


def test_a_killed_worker_loses_nothing(clients, scenes):
    """One of two workers killed (SIGKILL, by its process id) while tasks run: Dask
    reruns its tasks elsewhere and the image equals the undisturbed one."""
    client = clients[2]
    calm = distributed.render(scenes["path"], 16384, client=client, seed=9, tasks=16, progress=False).image
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    killed = kill_soon(victim)
    t0 = time.perf_counter()
    hurt = distributed.render(scenes["path"], 16384, client=client, seed=9, tasks=16, progress=False)
    assert killed.is_set(), "the render finished before the worker was killed (%.2f s)" % (time.perf_counter() - t0)
    assert victim not in client.run(os.getpid).values()
    assert np.array_equal(hurt.image, calm) and hurt.tasks_done == 16
    client.wait_for_workers(2, timeout=60)


def test_a_lone_worker_killed_loses_nothing(clients, scenes, monkeypatch):
    """The only worker killed while tasks run: the scene it held is lost with it, so its
    tasks are cancelled; the scene is scattered again to the worker the nanny starts and
    the tasks are submitted again: the undisturbed image. Test of the test: without
    scattering again the render stops, naming the lost data."""
    client = clients[1]
    calm = distributed.render(scenes["path"], 4096, client=client, seed=9, tasks=8, progress=False).image

    def hurt():
        killed = kill_soon(next(iter(client.run(os.getpid).values())))
        result = distributed.render(scenes["path"], 4096, client=client, seed=9, tasks=8, progress=False)
        assert killed.is_set(), "the render finished before the worker was killed"
        return result
    try:
        result = hurt()
        assert np.array_equal(result.image, calm) and result.tasks_done == 8
        client.wait_for_workers(1, timeout=60)

        def scattered_once(self):
            if self._future is None:
                self._future = self.client.scatter([self.data], broadcast=True, hash=False)[0]
            return self._future
        monkeypatch.setattr(dask_engine.Shipped, "future", scattered_once)
        with pytest.raises(dask_engine.TaskFailed, match="lost dependencies"):
            hurt()
    finally:
        client.wait_for_workers(1, timeout=60)


def test_a_render_uses_only_its_own_client(clients, scenes, monkeypatch):
    """A render on one client of several (here the module's three) tracks its tasks on
    that client's event loop, never on Dask's default client (the newest one): a task
    waited for again there after its data was lost failed as 'bound to a different event
    loop'. Made strict by taking the default client away. Test of the test: tracking on
    the default client's loop fails."""
    import distributed as dd
    import distributed.client as dc
    calm = distributed.render(scenes["path"], 16, client=clients[1], seed=3, tasks=2, progress=False).image

    def no_default():
        raise ValueError("no default client")
    monkeypatch.setattr(dc, "default_client", no_default)
    alone = distributed.render(scenes["path"], 16, client=clients[1], seed=3, tasks=2, progress=False)
    assert np.array_equal(alone.image, calm)
    tracked = dd.as_completed
    monkeypatch.setattr(dd, "as_completed", lambda futures, loop=None: tracked(futures))
    with pytest.raises(ValueError, match="no default client"):
        distributed.render(scenes["path"], 16, client=clients[1], seed=3, tasks=2, progress=False)


def test_a_task_the_scheduler_cancels_is_submitted_again(clients, scenes, monkeypatch):
    """A future cancelled without this render asking (the scheduler forgot its key: a
    run of the suite once lost a task so) is submitted again: the same image. Test of the
    test: without resubmission the render stops, naming the task."""
    client = clients[2]
    calm = distributed.render(scenes["path"], 16, client=client, seed=7, tasks=4, progress=False).image
    submit, cancelled = client.submit, []

    def cancelling(*args, **kwargs):
        future = submit(*args, **kwargs)
        if not cancelled:
            cancelled.append(future.key)
            client.cancel([future])
        return future
    monkeypatch.setattr(client, "submit", cancelling)
    again = distributed.render(scenes["path"], 16, client=client, seed=7, tasks=4, progress=False)
    assert cancelled and np.array_equal(again.image, calm) and again.tasks_done == 4
    monkeypatch.setattr(dask_engine, "RESUBMITS", 0)
    cancelled.clear()
    with pytest.raises(dask_engine.TaskFailed, match="Cancelled"):
        distributed.render(scenes["path"], 16, client=client, seed=7, tasks=4, progress=False)


def test_a_failing_task_stops_the_render_with_its_error(clients, tmp_path):
    """ray_bundle without first_shot refuses a delta light when it renders (the scene
    loads): the render stops with that error, naming the task, without hanging."""
    path = scene_copy(str(tmp_path), '<integrator type="ray_bundle"><boolean name="first_shot" value="false"/>'
                      '</integrator>', '<emitter type="point" id="bulb"><point name="position" x="0" y="0.5" '
                      'z="0"/></emitter>')
    t0 = time.perf_counter()
    with pytest.raises(dask_engine.TaskFailed, match=r"chain group \d of 4 .*delta light") as info:
        distributed.render(path, 4, client=clients[2], tasks=4, progress=False)
    assert isinstance(info.value.error, ValueError) and time.perf_counter() - t0 < 60


def test_ctrl_c_keeps_the_finished_passes(clients, scenes, monkeypatch):
    """Ctrl-C after the first finished task: the rest are cancelled and the image is the
    finished pass alone."""
    class Interrupting:
        def update(self, n):
            raise KeyboardInterrupt

        def close(self):
            pass
    monkeypatch.setattr(dask_engine, "_bar", lambda total, desc, show: Interrupting())
    res = distributed.render(scenes["path"], 8, client=clients[2], seed=4, tasks=4)
    assert res.interrupted and res.tasks_done == 1 and res.spp_done == 2
    one = passes.render_in_passes(mi.load_file(scenes["path"]), spp=8, passes=4, seed=4)
    assert res.image.shape == one.image.shape and np.all(np.isfinite(res.image))


def test_the_scene_and_its_files_are_shipped(tmp_path):
    """The bundle holds the scene and its relative mesh; written elsewhere (the
    original deleted) it loads and renders. A file referenced by an absolute path is not
    shipped and a worker without it says so by name."""
    path = scene_copy(str(tmp_path / "src"), INTEGRATORS["path"])
    b = scene_bundle.bundle(path)
    assert sorted(b.files) == sorted(["scene.xml", os.path.join("meshes", os.listdir(tmp_path / "src" / "meshes")[0])])
    shutil.rmtree(tmp_path / "src")
    image = np.array(mi.render(mi.load_file(scene_bundle.materialize(b)), spp=4))
    assert abs(image.mean() - 0.5) < 0.05
    b.absolute = ["/nonexistent/mesh.ply"]
    with pytest.raises(FileNotFoundError, match="'/nonexistent/mesh.ply' by absolute path"):
        scene_bundle.materialize(b)
    broken = scene_copy(str(tmp_path / "broken"), INTEGRATORS["path"])
    shutil.rmtree(tmp_path / "broken" / "meshes")
    with pytest.raises(FileNotFoundError, match="references 'meshes/.*which does not exist"):
        scene_bundle.bundle(broken)


def write_obj(path, triangles):
    """An OBJ mesh of ``triangles`` separate triangles: its vertex count (3 per
    triangle) tells which of several same-named files Mitsuba took."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.writelines("v %d 0 0\nv %d 1 0\nv %d 0 1\n" % (i, i, i) for i in range(triangles))
        f.writelines("f %d %d %d\n" % (3 * i + 1, 3 * i + 2, 3 * i + 3) for i in range(triangles))


def write_xml(path, *elements):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write('<scene version="3.0.0">\n    %s\n</scene>\n' % "\n    ".join(elements))
    return str(path)


def obj_shape(shape_id, filename):
    return '<shape type="obj" id="%s"><string name="filename" value="%s"/></shape>' % (shape_id, filename)


def vertex_counts(scene_file, **params):
    """{shape id: vertex count} of the scene as Mitsuba loads it."""
    return {s.id(): s.vertex_count() for s in mi.load_file(str(scene_file), **params).shapes()}


def loaded_on_a_worker(b, tmp_path, monkeypatch, **params):
    """The vertex counts of bundle ``b`` written into a fresh temporary directory, the
    original files (tmp_path/src) deleted first."""
    shutil.rmtree(tmp_path / "src")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "worker"))
    path = scene_bundle.materialize(b)
    assert path.startswith(str(tmp_path / "worker"))
    return vertex_counts(path, **params)


def test_a_fragment_names_meshes_relative_to_the_main_file(tmp_path, monkeypatch):
    """An included fragment's mesh paths are relative to the main file's folder (Mitsuba
    resolves a filename with the main file's search list, wherever it is written): the
    bundle ships that mesh, and written elsewhere the scene loads the same shapes."""
    src = tmp_path / "src"
    scene = write_xml(src / "scene.xml", '<include filename="fragments/shapes.xml"/>')
    write_xml(src / "fragments" / "shapes.xml", obj_shape("a", "meshes/x.obj"), obj_shape("b", "meshes/y.obj"))
    write_obj(src / "meshes" / "x.obj", 1)
    write_obj(src / "meshes" / "y.obj", 2)
    expected = vertex_counts(scene)
    assert expected == {"a": 3, "b": 6}
    b = scene_bundle.bundle(scene)
    assert sorted(b.files) == sorted(["scene.xml", os.path.join("fragments", "shapes.xml"),
                                      os.path.join("meshes", "x.obj"), os.path.join("meshes", "y.obj")])
    assert b.absolute == [] and loaded_on_a_worker(b, tmp_path, monkeypatch) == expected


def test_path_entries_are_searched_first_and_kept_on_the_workers(tmp_path, monkeypatch):
    """<path> folders come before the main file's folder, the last declared first, and a
    relative one is relative to the declaring file's folder: a mesh in both the main
    folder and 'assets' is the one in 'assets'; one found through '../common' (outside
    the main folder) is shipped in the same layout; 'empty' holds nothing but must exist
    on the worker (Mitsuba refuses a missing <path>); an absolute <path> and the file
    found through it are not shipped but checked by name."""
    src, shared = tmp_path / "src" / "scene", tmp_path / "shared_fs"
    scene = write_xml(src / "scene.xml", '<path value="../common"/>', '<path value="assets"/>',
                      '<path value="empty"/>', '<path value="%s"/>' % shared,
                      obj_shape("a", "x.obj"), obj_shape("b", "lib.obj"), obj_shape("c", "ext.obj"))
    write_obj(src / "x.obj", 1)
    write_obj(src / "assets" / "x.obj", 2)
    write_obj(tmp_path / "src" / "common" / "lib.obj", 3)
    write_obj(shared / "ext.obj", 4)
    os.makedirs(src / "empty")
    expected = vertex_counts(scene)
    assert expected == {"a": 6, "b": 9, "c": 12}
    b = scene_bundle.bundle(scene)
    assert sorted(b.files) == sorted([os.path.join("scene", "scene.xml"), os.path.join("scene", "assets", "x.obj"),
                                      os.path.join("common", "lib.obj")])
    assert b.scene == os.path.join("scene", "scene.xml") and os.path.join("scene", "empty") in b.folders
    assert b.absolute == sorted([str(shared), str(shared / "ext.obj")])
    assert loaded_on_a_worker(b, tmp_path, monkeypatch) == expected


def test_nested_includes_and_parameters_resolve_as_mitsuba_does(tmp_path, monkeypatch):
    """An include's name is searched in the including file's folder first, then in that
    file's <path> folders, then in the folders of the files that include it; a <default>
    and the given $parameters are substituted in every name. Decoys of the same names
    further down those lists (and a mesh relative to the fragment) are not what Mitsuba
    takes, and not what is shipped."""
    src = tmp_path / "src"
    scene = write_xml(src / "scene.xml", '<default name="part" value="walls"/>',
                      '<include filename="fragments/$part.xml"/>')
    write_xml(src / "fragments" / "walls.xml", '<path value="more"/>', '<include filename="floor.xml"/>',
              '<include filename="ceiling.xml"/>', obj_shape("wall", "meshes/$mesh.obj"))
    write_xml(src / "fragments" / "floor.xml", obj_shape("floor", "meshes/floor.obj"))
    write_xml(src / "fragments" / "more" / "ceiling.xml", obj_shape("ceiling", "meshes/floor.obj"))
    for decoy in [src / "fragments" / "more" / "floor.xml", src / "floor.xml", src / "ceiling.xml"]:
        write_xml(decoy, obj_shape("decoy", "meshes/floor.obj"))
    write_obj(src / "meshes" / "wall.obj", 1)
    write_obj(src / "fragments" / "meshes" / "wall.obj", 5)
    write_obj(src / "meshes" / "floor.obj", 2)
    expected = vertex_counts(scene, mesh="wall")
    assert expected == {"wall": 3, "floor": 6, "ceiling": 6}
    b = scene_bundle.bundle(scene, {"mesh": "wall"})
    assert sorted(b.files) == sorted(["scene.xml", os.path.join("fragments", "walls.xml"),
                                      os.path.join("fragments", "floor.xml"),
                                      os.path.join("fragments", "more", "ceiling.xml"),
                                      os.path.join("meshes", "wall.obj"), os.path.join("meshes", "floor.obj")])
    assert loaded_on_a_worker(b, tmp_path, monkeypatch, mesh="wall") == expected


def test_a_missing_file_names_its_fragment_and_the_folders_searched(tmp_path, monkeypatch):
    """A name Mitsuba finds nowhere: the message names the fragment that writes it, the
    name as written and as substituted, and the folders searched in order. A file Mitsuba
    finds only through the working directory (the workers' differs) is refused by name."""
    src = tmp_path / "src"
    os.makedirs(src / "assets")
    scene = write_xml(src / "scene.xml", '<path value="assets"/>', '<include filename="fragments/shapes.xml"/>')
    fragment = write_xml(src / "fragments" / "shapes.xml", obj_shape("a", "meshes/$name.obj"))
    with pytest.raises(Exception, match="none.obj"):
        mi.load_file(scene, name="none")
    with pytest.raises(FileNotFoundError) as e:
        scene_bundle.bundle(scene, {"name": "none"})
    assert ("references 'meshes/none.obj' (written 'meshes/$name.obj') (in %s), which does not exist in any folder "
            "Mitsuba searches for it: %s, %s, " % (fragment, src / "assets", src)) in str(e.value)
    write_obj(tmp_path / "cwd" / "meshes" / "stray.obj", 1)
    monkeypatch.chdir(tmp_path / "cwd")
    assert vertex_counts(scene, name="stray") == {"a": 3}
    with pytest.raises(FileNotFoundError, match=re.escape("finds only as '%s', through the working directory"
                                                          % (tmp_path / "cwd" / "meshes" / "stray.obj"))):
        scene_bundle.bundle(scene, {"name": "stray"})


def test_adaptive_qmc_is_refused(clients, tmp_path):
    path = scene_copy(str(tmp_path), '<integrator type="qmc_lighttrace"><float name="epsilon" value="0.01"/>'
                      '</integrator>')
    with pytest.raises(ValueError, match="qmc_lighttrace: epsilon=0.01 .* valid for distributed rendering"):
        distributed.render(path, 2, client=clients[1], progress=False)


def test_without_dask_the_option_says_how_to_install(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(ImportError, match=re.escape("pip install 'mi-plugins[distributed]'")):
        distributed.render(KELLER, 2)


def test_cli_render_with_workers(tmp_path):
    """`mi-plugins render SCENE --workers 2`: the EXR and its metadata."""
    import subprocess
    out = tmp_path / "out.exr"
    r = subprocess.run([sys.executable, "-m", "mi_plugins", "render", KELLER, "-o", str(out), "--spp", "8",
                        "--workers", "2", "--tasks", "4", "--seed", "1"], capture_output=True, text=True, cwd=REPO,
                       timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "finished 4/4 tasks on 2 workers (8 spp" in r.stdout
    image, meta = exr.read(str(out))
    assert meta["workers"] == "2" and meta["passes"] == "4/4" and abs(image.mean() - 0.5) < 0.02
    bad = subprocess.run([sys.executable, "-m", "mi_plugins", "render", KELLER, "-o", str(out), "--workers", "0"],
                         capture_output=True, text=True, cwd=REPO, timeout=300)
    assert bad.returncode == 2 and "--workers 0: valid range: 1 or more" in bad.stderr


def test_a_users_own_cluster_gets_the_callers_variant(tmp_path, monkeypatch):
    """A LocalCluster the user made (no MI_PLUGINS_VARIANT in its workers' environment):
    the package sets the caller's variant on every worker before the first task (the
    workers import the package to unpickle a task, which needs a variant)."""
    from distributed import Client, LocalCluster
    monkeypatch.delenv("MI_PLUGINS_VARIANT", raising=False)
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0")
    client = Client(cluster)
    try:
        path = scene_copy(str(tmp_path), INTEGRATORS["stochastic_ray"])
        result = distributed.render(path, 2, client=client, tasks=2, progress=False)
        assert result.tasks_done == 2 and np.all(np.isfinite(result.image)) and result.image.mean() > 0.1
        variants = client.run(lambda: __import__("mitsuba").variant())
        assert set(variants.values()) == {mi.variant()}
    finally:
        client.close()
        cluster.close()


def _two_sensors(path):
    """The scene at ``path`` with a second sensor (moved 0.1 along x)."""
    text = open(path).read()
    start = text.index('<sensor type="perspective">')
    sensor = text[start:text.index("</sensor>", start) + len("</sensor>")]
    other = sensor.replace('-0.459800482 0.400000006', '-0.459800482 0.300000006')
    with open(path, "w") as f:
        f.write(text.replace(sensor, sensor + "\n    " + other))
    return path


@pytest.mark.parametrize("integrator", ["qmc_lighttrace", "path"])
def test_views_share_one_solve_shipped_to_every_worker(integrator, clients, tmp_path):
    """Every sensor a task; a solution integrator solves once (its own task) and ships
    the solution: each view equals the single-process render from the same solution."""
    xml = {"qmc_lighttrace": '<integrator type="qmc_lighttrace"><integer name="samples" value="20000"/>'
                             '<string name="display" value="smooth"/></integrator>',
           "path": INTEGRATORS["path"]}[integrator]
    path = _two_sensors(scene_copy(str(tmp_path), xml))
    result = distributed.render_views(path, 4, client=clients[2], seed=3, progress=False)
    assert len(result.images) == 2 and result.solves == (integrator != "path")
    scene = mi.load_file(path, parallel=False, optimize=False)
    for k, image in enumerate(result.images):
        local = np.array(mi.render(scene, sensor=k, spp=4, seed=3))
        np.testing.assert_allclose(image, local, rtol=1e-5, atol=1e-6)
    if integrator != "path":
        assert scene.integrator().solve_count == 1
    assert not np.allclose(result.images[0], result.images[1])


def test_cli_renders_every_sensor(tmp_path):
    from mi_plugins.app import cli
    xml = ('<integrator type="qmc_lighttrace"><integer name="samples" value="20000"/>'
           '<string name="display" value="smooth"/></integrator>')
    path = _two_sensors(scene_copy(str(tmp_path), xml))
    out = str(tmp_path / "view.exr")
    assert cli.main(["render", path, "-o", out, "--spp", "2", "--sensors", "all", "--preview-every", "4"]) == 0
    images = [exr.read(str(tmp_path / ("view_%d.exr" % k)))[0] for k in (0, 1)]
    assert images[0].shape == images[1].shape and not np.allclose(images[0], images[1])
    assert cli.main(["render", path, "-o", out, "--spp", "2", "--sensors", "0,7"]) == 2
