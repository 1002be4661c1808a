"""View-independent solutions of ``ray_bundle`` and ``qmc_lighttrace``: the smooth field,
the display modes, the reuse of a solution across renders, files and exported meshes.

Every statistical check goes through the harness or ``budget.close`` (fixed seeds,
bounds from measured standard errors); every check has its test of the test.
"""
import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import budget
import mi_plugins
from mi_plugins.verify import analytic
from mi_plugins.solution import patchfield, views
from mi_plugins.patches.meshtable import MeshTable
from mi_plugins.solution.solution import Solution, SolutionMismatch

T = mi.ScalarTransform4f
DISPLAYS = ("smooth", "patches", "baked")
INTEGRATORS = ("qmc_lighttrace", "ray_bundle")


def _sensor(origin=(0, 2.5, 2.5), target=(0, 0, 0), size=8):
    return {"type": "perspective", "fov": 45, "to_world": T().look_at(origin=list(origin), target=list(target),
                                                                       up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}}}


def _floor_scene(shape="rectangle", extra=None):
    """A 2 x 2 floor (analytic rectangle or a two-triangle mesh) and a wall meeting it."""
    floor = ({"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90)} if shape == "rectangle" else
             {"type": "obj", "filename": _quad_file()})
    d = {"type": "scene", "floor": dict(floor, bsdf={"type": "diffuse"}),
         "wall": {"type": "rectangle", "to_world": T().translate([0, 1, -1]),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.4, 0.3]}}},
         "lamp": {"type": "point", "position": [0.3, 1.5, 0.4], "intensity": {"type": "rgb", "value": 4.0}},
         "sensor": _sensor()}
    d.update(extra or {})
    return mi.load_dict(d)


def _quad_file():
    path = os.path.join(budget.REPO, "reports", "test_solution_quad.obj")
    if not os.path.exists(path):
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path + ".tmp%d" % os.getpid(), "w") as f:
            f.write("v -1 0 1\nv 1 0 1\nv 1 0 -1\nv -1 0 -1\nf 1 2 3\nf 1 3 4\n")
        os.replace(path + ".tmp%d" % os.getpid(), path)
    return path


# ------------------------------------------------------------------ the smooth field
def _linear(points):
    return 1.0 + 0.3 * points[:, 0] - 0.7 * points[:, 1] + 0.45 * points[:, 2]


def _field_error(shape, h):
    """Largest error of the interpolated field of a linear function (patch values at the
    centroids) at random points of every patch, evaluated by the kernels' weights."""
    if shape == "clusters":
        from test_meshtable import _fine_mesh
        scene = _fine_mesh(power=1.6)
    else:
        scene = _floor_scene(shape)
    table = MeshTable(scene, "test", h=h)
    field = patchfield.PatchField(table)
    vertex = field.fit(_linear(field.centroids)[:, None])
    rng = budget.rng(11)
    k = table.front_count
    patch = np.repeat(np.arange(k), 4)
    sample = rng.random((len(patch), 2))
    si = table.surface_interaction(mi.UInt32(patch.astype(np.uint32)), mi.Point2f(sample[:, 0], sample[:, 1]))
    found, element, mesh, a, b = table.locate(si)
    assert np.array_equal(np.array(found), patch)
    ids, w = field.weights(element, mesh, a, b)
    values = mi.Float(vertex[:, 0])
    got = np.array(sum((w[j] * dr.gather(mi.Float, values, ids[j]) for j in range(4)), mi.Float(0.0)))
    points = np.array(si.p, dtype=np.float64).T
    return float(np.abs(got - _linear(points)).max())


@pytest.mark.parametrize("shape,h", [("rectangle", 0.3), ("mesh", 0.3), ("clusters", 0.5)])
def test_a_linear_field_is_reconstructed_exactly(shape, h):
    """Border and corner vertices included (least-squares planes), the inner vertices of
    clusters too (their cluster's plane), to float precision."""
    assert _field_error(shape, h) < 2e-5


def test_the_area_weighted_mean_alone_is_not_exact(monkeypatch):
    """Test of the test: vertex values as the plain mean of the patches around them are
    off at the borders."""
    monkeypatch.setattr(patchfield, "MIN_SPREAD", 2.0)       # no plane anywhere: the mean
    assert _field_error("mesh", 0.3) > 0.02


def test_vertices_are_welded_across_sub_triangles_but_not_across_a_crease():
    scene = _floor_scene("mesh")
    table = MeshTable(scene, "test", h=0.3)
    field = patchfield.PatchField(table)
    positions = np.round(field.vertex_positions, 5)
    # the floor's sub-triangles share their corners: about one vertex per lattice point
    floor = field.element_normals[:, 1] > 0.5
    used = np.unique(field.vertex_ids[floor, :3])
    assert len(used) < 0.6 * 3 * floor.sum()
    # the corner line where the floor meets the wall (z = -1, y = 0) has a vertex per surface
    edge = np.flatnonzero((np.abs(positions[:, 2] + 1) < 1e-4) & (np.abs(positions[:, 1]) < 1e-4))
    kinds = {bool(floor[e]) for e in np.flatnonzero(np.isin(field.vertex_ids, edge).any(axis=1))}
    assert kinds == {True, False}
    assert len({tuple(p) for p in positions[edge]}) < len(edge)     # coincident, not welded


# ------------------------------------------------------------------ exact where the solution is
CONSTANT = {"furnace": lambda: analytic.furnace(albedo=0.5, emission=0.5, geometry="box", resolution=8),
            "keller_cube": lambda: analytic.keller_cube(resolution=8)}


@pytest.mark.parametrize("case,integrator", [(c, i) for c in CONSTANT for i in INTEGRATORS],
                         ids=["%s-%s" % (c, i) for c in CONSTANT for i in INTEGRATORS])
def test_displays_are_exact_in_constant_radiance_scenes(case, integrator):
    """The smooth and the flat display of each run's one solve (the display mode is read
    at every render; the solution is kept for its scene and seed) against the exact
    radiance, each by the harness's comparison."""
    from mi_plugins.verify.analytic import harness
    constant = CONSTANT[case]()
    scene = constant.scene({"type": integrator, "display": "smooth"})
    integ = scene.integrator()
    images = {"smooth": [], "patches": []}
    for r in range(16):
        for display, runs in images.items():
            integ.display = display
            runs.append(np.array(mi.render(scene, spp=8, seed=harness.run_seed(budget.seed(20), r)), dtype=np.float64))
    assert integ.solve_count == 16
    for display, runs in images.items():
        out = harness.compare(np.stack(runs), constant.expected(-1))
        assert out["passed"], (display, out)


@pytest.mark.parametrize("integrator,display", [(i, d) for i in INTEGRATORS for d in ("gather", "smooth")],
                         ids=["%s-%s" % (i, d) for i in INTEGRATORS for d in ("gather", "smooth")])
def test_clustered_patches_are_exact_in_the_furnace(integrator, display):
    """The furnace inside a sphere mesh of 1280 triangles, clustered by a patch size of
    0.6 (about 90 patches): constant radiance stays exact."""
    case = analytic.furnace(albedo=0.5, emission=0.5, geometry="sphere_mesh", resolution=8)
    cfg = {"type": integrator, "display": display, "patch_size": 0.6}
    scene = case.scene(cfg)
    table = scene.integrator().patch_table(scene)
    assert 40 < table.count < 200 < table.element_count
    out = analytic.check(case, cfg, spp=8 if display == "smooth" else (1 if integrator == "ray_bundle" else 16),
                         runs=8, seed=budget.seed(21))
    assert out.passed, out


@pytest.mark.parametrize("display", ["patches", "smooth", "baked"])
def test_displays_of_the_bundles_that_carry_the_direct_light(display):
    """ray_bundle without first_shot (the paper's algorithm) keeps the direct light in its
    tables, and the displays add none: exact in the furnace, and no pixel read past the
    end of a stand-in array (the patches display did: NaN and -1e35 pixels)."""
    cfg = {"type": "ray_bundle", "display": display, "first_shot": False}
    case = CONSTANT["furnace"]()
    image = np.array(mi.render(case.scene(cfg), spp=4, seed=budget.seed(22)))
    assert np.all(np.isfinite(image)) and np.all(image >= 0), image.min()
    out = analytic.check(case, cfg, spp=8, runs=16, seed=budget.seed(20))
    assert out.passed, out


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_a_wrong_solution_fails_the_constant_radiance_check(integrator, monkeypatch):
    """Test of the test: the stored light 10 % too high (the image 2.5 % too bright) fails
    the furnace."""
    original = Solution.vertex_values

    def scaled(self, name):
        return original(self, name) * (1.1 if name == "tables" else 1.0)
    monkeypatch.setattr(Solution, "vertex_values", scaled)
    out = analytic.check(CONSTANT["furnace"](), {"type": integrator, "display": "smooth"}, spp=8, runs=16,
                         seed=budget.seed(20))
    assert not out.passed, out


# ------------------------------------------------------------------ reuse
@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_a_solution_is_kept_for_its_scene_and_seed(integrator):
    scene = _floor_scene("mesh", {"other": _sensor(origin=(1.5, 2.0, 2.5))})
    integ = mi.load_dict({"type": integrator, "display": "smooth"})
    mi.render(scene, integrator=integ, spp=2, seed=budget.seed(3))
    first = integ._cached[1]
    # another sensor and another spp: the same solution, not solved again
    mi.render(scene, integrator=integ, sensor=1, spp=4, seed=budget.seed(3))
    assert integ.solve_count == 1 and integ._cached[1] is first
    # the same render again: the same image, bit for bit
    a = np.array(mi.render(scene, integrator=integ, spp=2, seed=budget.seed(3)))
    b = np.array(mi.render(scene, integrator=integ, spp=2, seed=budget.seed(3)))
    assert np.array_equal(a, b) and integ.solve_count == 1
    # another seed solves again
    mi.render(scene, integrator=integ, spp=2, seed=budget.seed(4))
    assert integ.solve_count == 2
    # an edited scene solves again, and so does another scene object with the same content
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("reflectance.value"))
    params[key] = type(params[key])(0.25)
    params.update()
    mi.render(scene, integrator=integ, spp=2, seed=budget.seed(4))
    assert integ.solve_count == 3
    mi.render(_floor_scene("mesh"), integrator=integ, spp=2, seed=budget.seed(4))
    assert integ.solve_count == 4


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_solves_on_the_same_patches_share_their_field(integrator):
    """The smooth field depends on the patches' geometry only: another seed's solve uses
    the first one's; a scene whose geometry moved gets its own, at the new positions."""
    scene = _floor_scene("mesh")
    integ = mi.load_dict({"type": integrator, "display": "smooth"})
    mi.render(scene, integrator=integ, spp=1, seed=budget.seed(3))
    first = integ._cached[1].field
    mi.render(scene, integrator=integ, spp=1, seed=budget.seed(4))
    assert integ.solve_count == 2 and integ._cached[1].field is first
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("vertex_positions"))
    moved = np.array(params[key]).reshape(-1, 3) - [0.0, 0.2, 0.0]
    params[key] = type(params[key])(moved.ravel())
    params.update()
    mi.render(scene, integrator=integ, spp=1, seed=budget.seed(4))
    second = integ._cached[1].field
    assert integ.solve_count == 3 and second is not first
    assert first.vertex_positions[:, 1].min() == pytest.approx(0.0, abs=1e-6)
    assert second.vertex_positions[:, 1].min() == pytest.approx(-0.2, abs=1e-6)


def test_qmc_lighttrace_keeps_its_particles_when_it_gathers():
    scene = _floor_scene("rectangle")
    integ = mi.load_dict({"type": "qmc_lighttrace"})
    mi.render(scene, integrator=integ, spp=2, seed=budget.seed(5))
    mi.render(scene, integrator=integ, spp=8, seed=budget.seed(5))
    assert integ.solve_count == 1


def test_ray_bundle_gathering_renders_solve_every_time():
    """'gather' images during its iterations (the paper's view-dependent estimate)."""
    scene = _floor_scene("rectangle")
    integ = mi.load_dict({"type": "ray_bundle", "iterations": 4})
    mi.render(scene, integrator=integ, spp=1, seed=budget.seed(5))
    mi.render(scene, integrator=integ, spp=1, seed=budget.seed(5))
    assert integ.solve_count == 0


def test_harness_runs_stay_independent():
    """analytic.check renders its runs with different seeds: one solve per run."""
    case = CONSTANT["furnace"]()
    scene = case.scene({"type": "qmc_lighttrace", "display": "smooth", "samples": 2000})
    images = analytic.harness.render_runs(scene, 2, 4, budget.seed(6))
    assert scene.integrator().solve_count == 4 and len({float(np.array(i).sum()) for i in images}) == 4


# ------------------------------------------------------------------ files and meshes
def test_save_and_load_round_trip_and_refusals(tmp_path):
    scene = _floor_scene("mesh")
    solution = mi_plugins.solve(scene, {"type": "qmc_lighttrace", "samples": 20000}, seed=budget.seed(7))
    path = solution.save(str(tmp_path / "floor.npz"))
    again = Solution.load(path, _floor_scene("mesh"))
    for name in ("tables", "direct", "radiance", "emission", "error", "areas"):
        assert np.array_equal(getattr(again, name), getattr(solution, name)), name
    # a loaded solution renders without solving
    integ = mi.load_dict({"type": "qmc_lighttrace", "samples": 20000, "display": "smooth"})
    integ.use_solution(Solution.load(path, scene))
    mi.render(scene, integrator=integ, spp=2, seed=budget.seed(7))
    assert integ.solve_count == 0
    with pytest.raises(SolutionMismatch, match="has no shape matching its shape 'floor'"):
        Solution.load(path, _floor_scene("rectangle"))
    with pytest.raises(SolutionMismatch, match="2 shapes; this scene has 3"):
        Solution.load(path, _floor_scene("mesh", {"box": {"type": "cube", "to_world": T().scale(0.1)}}))
    edited = _floor_scene("mesh")
    params = mi.traverse(edited)
    key = next(k for k in params.keys() if k.endswith("reflectance.value"))
    params[key] = type(params[key])(0.25)
    params.update()
    with pytest.raises(SolutionMismatch, match="content fingerprint"):
        Solution.load(path, edited)


def _box_in_two_orders():
    """The conformance suite's mesh Cornell box loaded from its dict as written and with its
    keys reversed: the same content, the shapes listed in another order (each wall its own
    reflectance, so that Mitsuba merges no meshes: merged meshes take their triangles in
    another order, and are then other shapes)."""
    from mi_plugins.verify.conformance import scene_library
    d = dict(scene_library.SCENES["cornell_mesh"][0](16))
    for k, name in enumerate(("floor", "ceiling", "back", "block")):
        d[name] = dict(d[name], bsdf={"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.6 + 0.01 * k}})
    return mi.load_dict(d), mi.load_dict({k: d[k] for k in reversed(list(d))})


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_a_solution_serves_its_scene_loaded_again_in_another_order(integrator, monkeypatch):
    """A solution handed to ``use_solution`` renders the same image on a scene of the same
    content whose shapes Mitsuba lists in another order (as it may on every load of one
    file): its patches are renumbered, not read in the solved scene's order; test of the
    test: read as they were stored, the image is wrong."""
    first, again = _box_in_two_orders()
    assert [s.id() for s in first.shapes()] != [s.id() for s in again.shapes()]
    params = {"type": integrator, "display": "patches", "samples": 20000, "iterations": 6, "burn_in": 2}
    params = {k: v for k, v in params.items() if k in ("type", "display") or
              (k == "samples") == (integrator == "qmc_lighttrace")}
    solving = mi.load_dict(params)
    a = np.array(mi.render(first, integrator=solving, spp=4, seed=budget.seed(8)))
    shown = mi.load_dict(params)
    shown.use_solution(solving.last_solution)
    b = np.array(mi.render(again, integrator=shown, spp=4, seed=budget.seed(8)))
    assert shown.solve_count == 0
    assert np.allclose(a, b, rtol=1e-4, atol=1e-6), np.abs(a - b).max()
    monkeypatch.setattr(Solution, "for_scene", lambda self, scene: self)
    stale = mi.load_dict(params)
    stale.use_solution(solving.last_solution)
    c = np.array(mi.render(again, integrator=stale, spp=4, seed=budget.seed(8)))
    assert np.abs(a - c).max() > 0.1 * a.max()


def _pixel_rays(scene, size=8):
    """One ray through the centre of every pixel of the scene's sensor."""
    idx = dr.arange(mi.UInt32, size * size)
    pos = (mi.Point2f(mi.Float(idx % size), mi.Float(idx // size)) + 0.5) / size
    return scene.sensors()[0].sample_ray(0.0, 0.0, pos, mi.Point2f(0.5))[0]


def test_exported_meshes_show_the_baked_field_in_mitsuba(tmp_path):
    """The PLY meshes' vertex colours, read back by Mitsuba's ``mesh_attribute`` texture, are
    the baked display's field: equal at the same surface points (one ray per pixel)."""
    from mi_plugins.solution import display
    scene = _floor_scene("mesh")
    integ = mi.load_dict({"type": "qmc_lighttrace", "samples": 20000, "display": "baked"})
    solution = integ.solve(scene, budget.seed(8))
    paths = solution.to_ply(str(tmp_path / "ply"))
    assert sorted(os.path.basename(p) for p in paths) == ["floor.ply", "wall.ply"]
    d = {"type": "scene", "sensor": _sensor()}
    for p in paths:
        d[os.path.basename(p)[:-4]] = {"type": "ply", "filename": p, "bsdf": {"type": "diffuse", "reflectance": 0.0},
                                        "emitter": {"type": "area", "radiance": {"type": "mesh_attribute",
                                                                                   "name": "vertex_color"}}}
    exported = mi.load_dict(d)
    ray = _pixel_rays(scene)
    hit = exported.ray_intersect(ray)
    ply = np.array(mi.Color3f(hit.emitter(exported).eval(hit, hit.is_valid())))
    table = MeshTable(scene, "test", h=solution.meta["patch_size"])
    view = display.View(solution, table, "baked")
    si = scene.ray_intersect(ray)
    baked = np.array(view.baked(si, mi.UInt32(0), si.is_valid()))
    flat = np.array(display.FlatTables(table, display._color(solution.radiance[None]))(si, mi.UInt32(0),
                                                                                     si.is_valid()))
    del exported
    seen = np.array(si.is_valid())
    floor = seen & (np.array(si.n.y) > 0.5)      # the mesh; the wall's cells are bilinear, exported as 2 triangles
    assert floor.sum() > 20 and np.array_equal(seen, np.array(hit.is_valid()))
    assert np.abs(ply - baked)[:, floor].max() < 1e-4 * baked.max()
    assert np.abs(ply - baked)[:, seen].max() < 0.05 * baked.max()
    assert np.abs(ply - flat)[:, floor].max() > 1e-2 * baked.max()      # test of the test: the flat patches differ
    # and the baked display renders that field (the emitter-free scene: its mean, 64 samples a pixel)
    image = np.array(mi.render(scene, integrator=integ, spp=64, seed=budget.seed(8)))
    assert integ.solve_count == 1 and abs(image.mean() / baked.mean() - 1) < 0.1


# ------------------------------------------------------------------ views and previews
def test_every_sensor_and_a_camera_path_from_one_solve():
    scene = _floor_scene("rectangle", {"other": _sensor(origin=(1.5, 2.0, 2.5))})
    integ = mi.load_dict({"type": "ray_bundle", "display": "smooth", "iterations": 8})
    images = views.render_views(scene, integ, "all", spp=2, seed=budget.seed(9))
    assert len(images) == 2 and integ.solve_count == 1
    path = views.orbit(scene, 4, turns=0.1)
    frames = views.render_camera_path(scene, integ, path, spp=2, seed=budget.seed(9))
    assert len(frames) == 4 and integ.solve_count == 1
    assert not np.array_equal(np.array(frames[0]), np.array(frames[3]))
    # the sensor is back where it was
    again = np.array(mi.render(scene, integrator=integ, spp=2, seed=budget.seed(9)))
    assert np.array_equal(again, np.array(images[0]))


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_previews_show_the_solution_as_it_goes(integrator):
    scene = _floor_scene("rectangle")
    integ = mi.load_dict({"type": integrator, "display": "smooth", "preview_every": 2})
    seen = []
    integ.preview_callback = lambda image, done, total: seen.append((done, total, float(np.array(image).mean())))
    mi.render(scene, integrator=integ, spp=2, seed=budget.seed(10))
    assert len(seen) >= 2 and all(total >= done > 0 and mean > 0 for done, total, mean in seen), seen


def test_ray_bundle_previews_begin_in_the_burn_in_and_leave_the_solution_as_it_was():
    """The first image comes after the first iteration (the burn-in's running average),
    and a solve with previews gives the solution of one without (up to float rounding: the
    burn-in's steps with previews are other kernels, which may round differently in the
    last bit: 2e-7 to 9e-7 relative over 12 seeds here, but the iterations can amplify a
    last bit, up to 3.5e-4 in the conformance suite's renders; a solution that kept the
    burn-in's iterations is 0.018 off)."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=16, height=16)
    scene = mi.load_dict(d)
    plain = mi.load_dict({"type": "ray_bundle", "display": "smooth", "iterations": 8, "burn_in": 4})
    expected = np.array(mi.render(scene, integrator=plain, spp=1, seed=budget.seed(11)))
    integ = mi.load_dict({"type": "ray_bundle", "display": "smooth", "iterations": 8, "burn_in": 4,
                          "preview_every": 1})
    seen = []
    integ.preview_callback = lambda image, done, total: seen.append((done, total, float(np.array(image).mean())))
    image = np.array(mi.render(scene, integrator=integ, spp=1, seed=budget.seed(11)))
    # (a burn-in extended by the convergence check counts again from 1)
    assert [d for d, _, _ in seen][:8] == list(range(1, 9)) and seen[0][2] > 0, seen
    assert np.allclose(image, expected, rtol=1e-3, atol=1e-6), (np.abs(image - expected).max(), seen)
