"""The interior benchmark's scenes (benchmarks/interiors.py) load and render: every scene at
16 x 12 px with `path` at 1 spp gives a finite image that is not black, and its camera
path has 60 views at eye height inside the scene."""
import os
import sys

import mitsuba as mi
import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
import interiors  # noqa: E402


def problems(image):
    """What is wrong with a smoke render: not finite, or black (mean below 1e-3)."""
    out = []
    if not np.all(np.isfinite(image)):
        out.append("non-finite pixels")
    elif float(np.mean(image)) < 1e-3:
        out.append("black (mean %.3g)" % float(np.mean(image)))
    return out


def smoke(d):
    scene = mi.load_dict(d)
    return np.array(mi.render(scene, integrator=mi.load_dict({"type": "path"}), spp=1, seed=3))


@pytest.mark.parametrize("name", interiors.SCENES)
def test_every_scene_loads_and_renders(name):
    image = smoke(interiors.scene_dict(name, 16))
    assert image.shape == (12, 16, 3)
    assert problems(image) == [], name


def test_the_smoke_check_fails_a_scene_without_its_lights_and_bad_images():
    d = interiors.scene_dict("room", 16)
    for key in interiors.lights("room"):
        del d[key]
    assert problems(smoke(d)) == ["black (mean 0)"]
    assert problems(np.full((2, 2, 3), np.nan)) == ["non-finite pixels"]


def test_camera_paths_walk_inside_the_scenes_at_eye_height():
    for name in interiors.SCENES:
        views = interiors.camera_path(name)
        origins = np.array([np.array(t.matrix)[:3, 3] for t in views])
        assert len(views) == 60
        assert np.allclose(origins[:, 2], interiors.EYE)
        assert np.all(origins[:, :2] > 0) and np.all(origins[:, :2] < interiors.SIZES[name]), name
