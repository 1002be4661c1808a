"""``mi-plugins demo``: every image written, the smooth displays solved once, the checks' lines."""
import os

import mitsuba as mi
import pytest

from mi_plugins import demo

pytestmark = pytest.mark.skipif(not mi.variant(), reason="needs a Mitsuba variant")


def test_demo_writes_every_image_with_its_errors(tmp_path):
    lines = []
    assert demo.run(str(tmp_path), seconds=0.2, resolution=16, check=False, out=lines.append) == 0
    names = sorted(os.listdir(tmp_path))
    for name in demo.INTEGRATORS:
        assert name.replace(" ", "_") + ".png" in names, names
    assert "contact_sheet.png" in names and "reference_path.png" in names
    rows = lines[1:-1]
    assert len(rows) == len(demo.INTEGRATORS) and all("away from the lamp" in row for row in rows), lines
    assert sum("1 solve," in row for row in rows) == 2, rows


def test_a_display_doubles_its_camera_samples_on_one_solve():
    scene = mi.load_dict(demo.cornell(16))
    image, spp, _, solves = demo.equal_time_display(scene, {"type": "qmc_lighttrace", "display": "smooth",
                                                            "samples": 20000}, 1.5)
    assert solves == 1 and spp >= 4 * demo.DISPLAY_SPP and image.mean() > 0
