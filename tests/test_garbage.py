"""Garbage collection around the package's renders (mi_plugins.base.collection).

Dr.Jit traces a call through a plugin pointer for every live instance of the plugin's
kind; an instance freed by a garbage collection while such a call is traced (in another
thread: a Dask worker's event loop) is used after it was freed. A run of the suite once
crashed a worker so, and failed another with "jit_registry_id(...): pointer is not
registered": a ray_bundle render had left its scene in reference cycles, and a collection
freed it while the worker traced the next scene. So: no render of the package leaves a
reference cycle that holds a Mitsuba object or a Dr.Jit array, the collector is off while a
render runs, and a worker's task collects at its end, in its own thread."""
import gc
import os
import weakref

import mitsuba as mi
import drjit as dr
import pytest

from conftest import REPO
from mi_plugins.base import collection
from mi_plugins.distributed import plan

CONFIGS = {
    "stochastic_ray": {"type": "stochastic_ray", "iterations": 6},
    "ray_bundle": {"type": "ray_bundle", "iterations": 6, "chains": 8},
    "ray_bundle-average": {"type": "ray_bundle", "iterations": 6, "chains": 8, "average_diffuse": True},
    "ray_bundle-smooth-refine-preview": {"type": "ray_bundle", "iterations": 8, "chains": 8, "display": "smooth",
                                         "refine": True, "preview_every": 2},
    "qmc_lighttrace": {"type": "qmc_lighttrace", "samples": 20000},
    "qmc_lighttrace-smooth-refine-preview": {"type": "qmc_lighttrace", "samples": 20000, "display": "smooth",
                                             "refine": True, "preview_every": 2},
    "qmc_lighttrace-baked": {"type": "qmc_lighttrace", "samples": 20000, "display": "baked"},
}


def held_by_garbage(make):
    """Run ``make()``, then collect: the Mitsuba objects and Dr.Jit arrays that only
    reference cycles held (their type names)."""
    gc.collect()
    make()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        gc.collect()
        pool = list(gc.garbage)
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
    held = sorted({type(r).__name__ for o in pool for r in gc.get_referents(o)
                   if r is not None and (isinstance(r, mi.Object) or dr.is_jit_v(r))})
    del pool
    gc.collect()
    return held


def cornell(integrator):
    scene = mi.cornell_box()
    scene["sensor"]["film"]["width"] = scene["sensor"]["film"]["height"] = 16
    scene["integrator"] = integrator
    return scene


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_a_render_leaves_no_cycle_holding_plugins_or_arrays(name):
    """Two renders (a second one replays what the first recorded) of a scene loaded for
    it, the scene dropped: nothing of it is left for a collection to free."""
    def render_twice():
        for seed in (1, 2):
            scene = mi.load_dict(cornell(CONFIGS[name]))
            integrator = scene.integrator()
            if hasattr(integrator, "preview_callback"):
                integrator.preview_callback = lambda image, done, total: None
            mi.render(scene, spp=4, seed=seed)
    assert held_by_garbage(render_twice) == []


@pytest.mark.parametrize("integrator", ["qmc_lighttrace", "ray_bundle"])
def test_a_scene_without_dark_splits_leaves_no_cycle(integrator):
    """Keller's cube (no patch lies partly in the dark: the table is its own unsplit base)."""
    def render():
        mi.render(mi.load_file(os.path.join(REPO, "configs", "keller_cube.xml"), integrator=integrator), spp=2)
    assert held_by_garbage(render) == []


def test_the_check_finds_a_cycle_that_holds_a_scene():
    """Test of the test: a scene and an array held by a reference cycle are found."""
    def cycle():
        box = {"scene": mi.load_dict(cornell({"type": "path"})), "array": mi.Float(1, 2)}
        box["self"] = box
    assert {"Scene", "Float"} <= set(held_by_garbage(cycle))


def test_the_collector_is_off_while_a_render_runs(monkeypatch):
    """Inside every package render (here: where its frame is rendered) the collector is off,
    on again after it; nested pauses keep it off until the outermost ends."""
    from mi_plugins.integrators.stochastic_ray import StochasticRayIntegrator
    seen, render_frame = [], StochasticRayIntegrator.render_frame

    def watched(self, frame):
        seen.append(gc.isenabled())
        return render_frame(self, frame)
    monkeypatch.setattr(StochasticRayIntegrator, "render_frame", watched)
    assert gc.isenabled()
    mi.render(mi.load_dict(cornell({"type": "stochastic_ray", "iterations": 2})), spp=1)
    assert seen == [False] and gc.isenabled()
    with collection.paused():
        with collection.paused():
            pass
        assert not gc.isenabled()
    assert gc.isenabled()


class Node:
    pass


def test_a_worker_task_collects_at_its_end_in_its_own_thread():
    """A worker function runs with the collector off and frees the cycles it left before it
    returns; its error is sent back as the integrator's own type. Test of the test: the
    same function unwrapped leaves its cycle to a later collection."""
    during, left = [], []

    def task(fail=False):
        during.append(gc.isenabled())
        node = Node()
        node.me = node
        left.append(weakref.ref(node))
        if fail:
            raise ValueError("the task's own error")
        return 1

    assert plan.worker_task(task)() == 1
    assert during == [False] and left[-1]() is None and gc.isenabled()
    with pytest.raises(ValueError, match="own error"):
        plan.worker_task(task)(True)
    assert left[-1]() is None and gc.isenabled()
    gc.disable()
    try:
        task()
        assert left[-1]() is not None
    finally:
        gc.enable()
    gc.collect()
    assert left[-1]() is None


def test_release_frees_the_last_scene_for_mitsubas_integrators():
    """The package keeps its last scene between renders (the next view starts at once), so
    that scene's plugins outlive the caller's reference to it, and Dr.Jit traces them in
    every later vcall: Mitsuba's ptracer on another scene traces a kept checkerboard area
    light's ray sampling, which raises. ``mi_plugins.release()`` frees the kept scene, and
    the same render then works."""
    import mi_plugins
    d = mi.cornell_box()
    d["light"]["emitter"]["radiance"] = {"type": "checkerboard", "color0": {"type": "rgb", "value": 0.2},
                                         "color1": {"type": "rgb", "value": 0.9}}
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = 8
    scene = mi.load_dict(dict(d, integrator={"type": "qmc_lighttrace", "samples": 1000}))
    mi.render(scene, spp=1)
    del scene
    gc.collect()
    other = mi.cornell_box()
    other["sensor"]["film"]["width"] = other["sensor"]["film"]["height"] = 8
    other = mi.load_dict(dict(other, integrator={"type": "ptracer"}))
    with pytest.raises(RuntimeError) as failed:
        mi.render(other, spp=1)
    assert "sample_spectrum" in str(failed.value) + str(failed.value.__cause__), failed.value
    mi_plugins.release()
    image = mi.render(other, spp=1)
    assert dr.all(dr.isfinite(image), axis=None) and dr.mean(image, axis=None) > 0
