"""Crowded patches (mi_plugins.patches.crowding): which patches they are, and the smooth
display, which gathers there instead of reading. The scene: a closed room with a shelf
of boards against its back wall and a block on the floor, lit by a ceiling lamp."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.patches import crowding
from mi_plugins.patches.crowding import crowded_patches
from mi_plugins.patches.meshtable import MeshTable
from mi_plugins.verify.conformance import runner

T = mi.ScalarTransform4f
RES, BLOCK = 32, 8


def shelf_room():
    def box(name, centre, half, value=0.6):
        return {"type": "cube", "to_world": T().translate(centre).scale(half),
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": value}}}
    scene = {"type": "scene",
             "room": dict(box("room", [0, 0, 0], [2, 1.5, 1.4]), flip_normals=True),
             "lamp": {"type": "rectangle", "to_world": T().translate([0, 1.49, 0.3]).rotate([1, 0, 0], 90).scale(0.4),
                      "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 12.0}}},
             "block": box("block", [0.9, -1.2, -0.3], [0.3, 0.3, 0.3], 0.4),
             "sensor": {"type": "perspective", "fov": 70,
                        "to_world": T().look_at(origin=[0.2, 0.1, 1.3], target=[0, -0.3, -1.4], up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}}}}
    for k, y in enumerate((-1.2, -0.7, -0.2, 0.3)):          # the shelf's boards, 30 cm deep
        scene["board%d" % k] = box("board", [-0.6, y, -1.25], [0.8, 0.02, 0.15], 0.5)
    scene["side"] = box("side", [-1.42, -0.45, -1.25], [0.02, 1.05, 0.15], 0.5)
    return scene


def test_the_crowded_patches_are_those_with_a_surface_close_by(monkeypatch):
    """Crowded: most of the floor's patches beside the block and of the wall's beside the boards;
    not the middle of the floor; more reach, more patches; none at reach 0; deterministic,
    in one block of patches or many; never an emitting shape's."""
    scene = mi.load_dict(shelf_room())
    table = MeshTable(scene, "test", h=0.2)
    centre = np.array(table.surface_interaction(dr.arange(mi.UInt32, table.front_count), mi.Point2f(0.5)).p).T
    room = np.array([s.id() == "room" for s in table.shapes])[table.shape_index_np[:table.front_count]]
    near, far = crowded_patches(table, 1.0), crowded_patches(table, 2.0)
    assert not crowded_patches(table, 0.0).any()
    assert np.all(far[near]) and far.sum() > near.sum()
    assert np.array_equal(near, crowded_patches(MeshTable(scene, "test", h=0.2), 1.0))
    monkeypatch.setattr(crowding, "CHUNK", 7)           # (blocks of patches: the same answer)
    assert np.array_equal(near, crowded_patches(MeshTable(scene, "test", h=0.2), 1.0))
    floor = room & (centre[:, 1] < -1.49)
    beside_block = floor & (np.abs(centre[:, 0] - 0.9) < 0.45) & (np.abs(centre[:, 2] + 0.3) < 0.45)
    open_floor = floor & (np.abs(centre[:, 0]) < 0.4) & (np.abs(centre[:, 2] - 0.5) < 0.4)
    boards = np.array([-1.2, -0.7, -0.2, 0.3])
    on_board = np.min(np.abs(centre[:, 1, None] - boards), axis=1) < 0.12
    beside_boards = room & (centre[:, 2] < -1.39) & (np.abs(centre[:, 0] + 0.6) < 0.6) & on_board
    assert near[beside_block].mean() > 0.5 and near[beside_boards].mean() > 0.5, (
        near[beside_block].mean(), near[beside_boards].mean())
    assert not near[open_floor].any()
    lamp = np.array([s.emitter() is not None for s in table.shapes])[table.shape_index_np[:table.front_count]]
    assert lamp.any() and not far[lamp].any()           # (an emitting shape is never crowded)


def _blocks(integrator, spp, seed, runs):
    images = runner.render_runs(shelf_room(), integrator, spp, [budget.seed(seed) * 1000 + r for r in range(runs)])[0]
    b = images[..., :3].mean(axis=-1).reshape(runs, RES // BLOCK, BLOCK, RES // BLOCK, BLOCK).mean(axis=(2, 4))
    return b.mean(axis=0), b.std(axis=0, ddof=1) / np.sqrt(runs)


@pytest.fixture(scope="module")
def reference():
    return _blocks({"type": "path"}, 1024, 90, 8)


def test_the_smooth_display_along_the_shelf_and_the_block(reference):
    """``qmc_lighttrace``'s smooth display at its default ``crowd_reach`` matches ``path``
    in every 8 x 8-pixel block within the noise and 0.3 % of stated bias (the smooth
    display's: docs/solutions.md; the largest deviation measured 0.3-0.4 of that bound).
    Test of the test: reading the stored light at the crowded patches too (``crowd_reach``
    0) puts the blocks along the shelf about 1-1.5 % too dark, 1.2-1.6 times the bound
    (two seed sets; z -10 and beyond at 800 000 particle paths)."""
    ref, ref_se = reference
    settings = {"type": "qmc_lighttrace", "display": "smooth", "samples": 400000}
    slack = 0.003 * ref
    mean, se = _blocks(settings, 64, 91, 8)
    budget.close(mean, ref, np.hypot(se, ref_se), slack=slack, what="smooth display's blocks / path")
    bad, bad_se = _blocks(dict(settings, crowd_reach=0.0), 64, 91, 8)
    assert np.any(np.abs(bad - ref) > budget.Z * np.hypot(bad_se, ref_se) + slack), np.round(100 * (bad / ref - 1), 1)
