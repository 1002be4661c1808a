"""The demo's walkthrough: the camera path, the cached per-frame cached_references, path and one
solve at equal time, the animation and the strip (a tiny budget: 16 px, 6 frames)."""
import os

import mitsuba as mi
import numpy as np
import pytest

from mi_plugins.app import animation, demo, cached_references, timesplit, walkthrough

pytestmark = pytest.mark.skipif(not mi.variant(), reason="needs a Mitsuba variant")

FRAMES = 6


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """The walk at 16 px, path 4 spp a frame, qmc_lighttrace from its smallest solve."""
    cache = str(tmp_path_factory.mktemp("references"))
    rate = timesplit.SolveRate({"type": "qmc_lighttrace", "display": "smooth"}, 0.0, 1.0)
    lines = []
    result = walkthrough.compare(16, {"qmc_lighttrace": rate}, frames=FRAMES, path_spp=4, cache=cache,
                                 out=lines.append)
    return result, lines, cache


def test_the_walk_stays_inside_the_box_or_at_its_opening():
    for transform in walkthrough.cornell_walk(40):
        origin = np.array(transform.matrix, dtype=np.float64)[:3, 3]
        assert np.all(np.abs(origin) < 1.0 + 1e-9), origin          # the box: [-1, 1]^3, open at z = 1
    with pytest.raises(ValueError, match="frames=1: valid: 2 or more"):
        walkthrough.cornell_walk(1)


def test_every_frame_has_its_error_and_each_solution_solved_once(walk):
    result, lines, _ = walk
    assert list(result.runs) == ["path", "qmc_lighttrace"] and len(result.reach["qmc_lighttrace"]) == 2
    for run in list(result.runs.values()) + result.reach["qmc_lighttrace"]:
        assert len(run.images) == FRAMES and run.errors.shape == (FRAMES, 2)
        assert np.all(np.isfinite(run.errors)) and np.all(run.errors > 0) and run.seconds > 0
        assert all(np.all(np.isfinite(image)) for image in run.images)
    assert [r.fraction for r in result.reach["qmc_lighttrace"]][0] == 0.25
    assert any("reaches path's error" in line for line in lines), lines
    assert sum(line.startswith("  %3d " % k) for line in lines for k in range(FRAMES)) == FRAMES, lines


def test_the_errors_are_per_frame(walk):
    """The test of the test: path's frames shown in reverse order miss their cached_references."""
    result, _, _ = walk
    path = result.runs["path"]
    wrong = walkthrough.Run(path.images[::-1], result.refs, path.seconds, "reversed")
    assert np.all(wrong.errors[[0, -1], 0] > 3 * path.errors[[0, -1], 0]), (wrong.errors, path.errors)
    assert np.all(wrong.worst_ratio(path) > 3)


def test_a_solution_reaches_path_only_where_every_frame_does(walk):
    """The time to reach path's error: the quickest run whose every frame is at most path's."""
    result, _, _ = walk
    path = result.runs["path"]
    fake = walkthrough.Walk(result.transforms, result.refs)
    fake.runs["path"] = path
    fake.runs["same"] = walkthrough.Run(path.images, result.refs, 2.0 * path.seconds, "path's own frames")
    fake.reach["same"] = [walkthrough.Run(path.images[::-1], result.refs, 0.1 * path.seconds, "reversed", 0.25)]
    assert fake.time_to_reach("same") == (pytest.approx(2.0 * path.seconds), pytest.approx(2.0))
    fake.runs["same"] = fake.reach["same"][0]
    assert fake.time_to_reach("same") is None


def test_the_references_are_read_back_from_the_cache(walk, monkeypatch):
    result, _, cache = walk
    monkeypatch.setattr(mi, "render", lambda *a, **k: pytest.fail("the cached reference was rendered again"))
    again = cached_references.path_references(walkthrough.scene_dict(16), walkthrough.REFERENCE_FACTOR * 4,
                                       result.transforms, tag="walk", cache=cache)
    assert all(np.array_equal(a.image, b.image) for a, b in zip(again, result.refs))
    other = cached_references.cache_file("walk", "another key", cache=cache)
    assert not os.path.exists(other)


def test_the_animation_and_the_strip_are_written(walk, tmp_path):
    result, _, _ = walk
    lines = []
    demo.walk_pictures(str(tmp_path), result, lines.append)
    from PIL import Image
    with Image.open(tmp_path / "walkthrough.gif") as gif:
        assert gif.n_frames == FRAMES and gif.is_animated
        assert gif.size[0] == 2 * 16 + animation.PAD                 # path and qmc_lighttrace side by side
    with Image.open(tmp_path / "walkthrough_strip.png") as strip:
        assert strip.size[0] >= 5 * 16
    assert any("walkthrough.gif (%d frames)" % FRAMES in line for line in lines), lines


def test_without_pillow_the_animation_is_skipped_with_the_reason(walk, tmp_path, monkeypatch):
    result, _, _ = walk
    monkeypatch.setattr(animation, "available", lambda: "Pillow is not installed (test)")
    lines = []
    demo.walk_pictures(str(tmp_path), result, lines.append)
    assert lines == ["walkthrough animation and strip skipped: Pillow is not installed (test)"]
    assert not os.listdir(tmp_path)


@pytest.mark.renders_nothing
def test_an_animation_with_a_missing_frame_is_refused(tmp_path):
    frames = [np.zeros((4, 4, 3))] * 3
    with pytest.raises(ValueError, match="the same number of frames and captions"):
        animation.write_animation(str(tmp_path / "a.gif"), [(frames, [["a"]] * 3), (frames[:2], [["b"]] * 2)])
