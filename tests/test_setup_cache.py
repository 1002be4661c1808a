"""The setup cache (mi_plugins.patches.setup_cache): a scene rendered again, as a new scene
object or in another process, takes its patches, dark splits, gap mouths and smooth field
from the cache and gives the same image; another scene, other settings or a damaged entry
build afresh; ``off`` writes nothing."""
import os
import subprocess
import sys

import mitsuba as mi
import numpy as np
import pytest

from mi_plugins.patches import build, darkness, gaps, meshtable, setup_cache
from mi_plugins.solution import patchfield

INTEGRATORS = ({"type": "qmc_lighttrace", "display": "smooth", "samples": 20000},
               {"type": "ray_bundle", "display": "smooth", "iterations": 8})


def scene_dict(reflectance=0.5):
    """Mitsuba's Cornell box with a BSDF of its own on every white surface (Mitsuba merges
    meshes that share a BSDF, in an order that varies from load to load: another merged
    mesh, another entry)."""
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = 16
    for k, name in enumerate(("floor", "ceiling", "back", "large-box")):
        if name in d:
            d[name]["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.7 + 0.01 * k}}
    d["small-box"]["bsdf"] = {"type": "diffuse", "reflectance": {"type": "rgb", "value": reflectance}}
    return d


def render(d, integrator, scene=None):
    build._LAST.clear()            # (a new process's state: no table of an earlier scene)
    scene = scene or mi.load_dict(d)
    return np.array(mi.render(scene, integrator=integrator if not isinstance(integrator, dict)
                              else mi.load_dict(integrator), spp=4, seed=1))


def reordered(d, first):
    """``d`` loaded with its shapes in another order than ``first``'s (Mitsuba's load
    order varies; the dict's reversed keys make it differ)."""
    keys = [k for k in d if k != "type"]
    other = {"type": "scene", **{k: d[k] for k in reversed(keys)}}
    ids = [s.id() for s in first.shapes()]
    for _ in range(20):
        scene = mi.load_dict(other, parallel=False)
        if [s.id() for s in scene.shapes()] != ids:
            return scene
    raise AssertionError("no other shape order")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(setup_cache.ENV, str(tmp_path / "setup"))
    return tmp_path / "setup"


def forbid_building(monkeypatch):
    """Every builder the cache stands in for raises."""
    def refuse(*args, **kwargs):
        raise AssertionError("built although cached")
    monkeypatch.setattr(meshtable, "_checked_mesh_part", refuse)
    monkeypatch.setattr(build, "split_in_the_dark", refuse)
    monkeypatch.setattr(patchfield.PatchField, "__init__", refuse)
    monkeypatch.setattr(darkness, "dark_fractions", refuse)


@pytest.mark.parametrize("integrator", INTEGRATORS, ids=lambda d: d["type"])
def test_a_scene_rendered_again_takes_its_setup_from_the_cache(cache, monkeypatch, integrator):
    first = render(scene_dict(), integrator)
    assert len(list(cache.rglob("*.npz"))) >= 4          # parts, dark rounds, gap mouths, field
    forbid_building(monkeypatch)
    again = render(scene_dict(), integrator)
    assert np.allclose(again, first, rtol=1e-4, atol=1e-5)


def setup_of(scene, back_sides):
    """(table, gap mouths, smooth field) of ``scene`` as a render builds them."""
    build._LAST.clear()
    table = build.cached_table(scene, "test", 0.15, back_sides=back_sides, dark_levels=2)
    return table, gaps.mouth_patches(table), patchfield.field_of(table)


def disagreement(first, other):
    """Largest difference between the setup ``first`` and ``other`` (of the same scene
    loaded in another shape order) once ``other``'s patches and elements are put in
    ``first``'s order: areas, normals, gap mouths, and the field's value at every element
    corner for the same patch values."""
    (ta, ma, fa), (tb, mb, fb) = first, other
    order = setup_cache.ShapeOrder(tb, setup_cache.digests_of(ta))
    p, e = order.patch, order.element
    values = np.random.default_rng(0).random((fa.count, 3))
    corners_a = fa.fit(values)[fa.vertex_ids.astype(np.int64)][e]
    corners_b = fb.fit(values[p])[fb.vertex_ids.astype(np.int64)]
    return max(float(np.abs(tb.areas_np[:tb.front_count] - ta.areas_np[p]).max()),
               float(np.abs(tb.normals_np[:tb.front_count] - ta.normals_np[p]).max()),
               float(np.sum(mb != ma[p])), float(np.abs(corners_a - corners_b).max()))


@pytest.mark.parametrize("back_sides", (False, True))
def test_a_scene_loaded_in_another_shape_order_renumbers_the_stored_setup(cache, monkeypatch, back_sides):
    """Mitsuba orders a scene's shapes differently from one load to the next: the stored
    dark splits, gap mouths and field are renumbered to the new order (the same setup,
    patch for patch); the test of the test: taken as stored, they are not."""
    first_scene = mi.load_dict(scene_dict(), parallel=False)
    first = setup_of(first_scene, back_sides)
    other = reordered(scene_dict(), first_scene)
    forbid_building(monkeypatch)
    assert disagreement(first, setup_of(other, back_sides)) < 1e-9
    renumbering = setup_cache.ShapeOrder.__init__

    def as_stored(self, table, stored):
        renumbering(self, table, stored)
        self.shape, self.identity = np.arange(len(self.shape)), True

    monkeypatch.setattr(setup_cache.ShapeOrder, "__init__", as_stored)
    wrong = setup_of(other, back_sides)
    monkeypatch.setattr(setup_cache.ShapeOrder, "__init__", renumbering)
    assert disagreement(first, wrong) > 0.01


def test_another_scene_or_other_settings_build_afresh(cache, monkeypatch):
    render(scene_dict(), INTEGRATORS[0])
    forbid_building(monkeypatch)
    with pytest.raises(Exception, match="built although cached"):
        render(scene_dict(reflectance=0.3), INTEGRATORS[0])
    with pytest.raises(Exception, match="built although cached"):
        render(scene_dict(), dict(INTEGRATORS[0], patch_size=0.4))


def test_a_damaged_entry_is_built_again(cache):
    first = render(scene_dict(), INTEGRATORS[0])
    paths = list(cache.rglob("*.npz"))
    for path in paths:
        path.write_bytes(b"not an npz file")
    again = render(scene_dict(), INTEGRATORS[0])
    assert np.all(np.isfinite(again)) and abs(again.mean() / first.mean() - 1) < 0.05
    assert sum(setup_cache.load(path.stem) is not None for path in cache.rglob("*.npz")) >= 4   # (written anew)


def test_off_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv(setup_cache.ENV, "off")
    assert setup_cache.directory() is None
    render(scene_dict(), INTEGRATORS[0])
    assert not list(tmp_path.rglob("*.npz"))


@pytest.mark.parametrize("value", ["0", "false", "No"])
def test_a_switch_instead_of_a_folder_is_refused(value, monkeypatch):
    """``MI_PLUGINS_SETUP_CACHE=0`` (or another switch word) is refused by name instead of
    making a folder '0' in the working directory; ``off`` turns the cache off."""
    monkeypatch.setenv(setup_cache.ENV, value)
    with pytest.raises(ValueError, match="MI_PLUGINS_SETUP_CACHE=.*'off'"):
        setup_cache.directory()


def test_another_process_reuses_the_setup(cache):
    code = ("import sys, time, numpy as np, mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import mi_plugins\n"
            "sys.path.insert(0, %r)\nfrom test_setup_cache import scene_dict, INTEGRATORS\n"
            "from mi_plugins.patches import setup_cache\n"
            "hits = []\nload = setup_cache.load\n"
            "setup_cache.load = lambda entry: hits.append(load(entry) is not None) or load(entry)\n"
            "img = np.array(mi.render(mi.load_dict(scene_dict()), integrator=mi.load_dict(INTEGRATORS[0]), spp=4,"
            " seed=1))\nprint('HITS', sum(hits), len(hits), 'MEAN', img.mean())" % os.path.dirname(__file__))
    env = dict(os.environ, **{setup_cache.ENV: str(cache)})
    runs = [subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
            for _ in range(2)]
    lines = [next(l for l in r.stdout.splitlines() if l.startswith("HITS")).split() for r in runs]
    assert lines[0][1] == "0", runs[0].stdout + runs[0].stderr
    assert lines[1][1] == lines[1][2] != "0", runs[1].stdout + runs[1].stderr
    assert abs(float(lines[0][4]) / float(lines[1][4]) - 1) < 1e-4


def test_pack_round_trip():
    fields = {"a": np.arange(5), "n": 7, "x": 0.25, "t": (np.zeros(2), np.ones((2, 3))), "e": ()}
    back = setup_cache.unpack(setup_cache.pack(fields))
    assert back["n"] == 7 and back["x"] == 0.25 and back["e"] == ()
    assert np.array_equal(back["a"], fields["a"]) and all(np.array_equal(u, v) for u, v in zip(back["t"], fields["t"]))
