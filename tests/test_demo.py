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


def test_a_display_doubles_its_camera_samples_on_one_solve(monkeypatch):
    """(a clock that advances 0.1 s per reading: the loop's decisions, not the machine's speed)"""
    ticks = iter(range(10 ** 6))
    monkeypatch.setattr(demo.time, "perf_counter", lambda: 0.1 * next(ticks))
    scene = mi.load_dict(demo.cornell(16))
    image, spp, spent, solves = demo.equal_time_display(scene, {"type": "qmc_lighttrace", "display": "smooth",
                                                                "samples": 20000}, 2.0)
    # short renders: the samples double until the next render would pass the 2 s
    assert solves == 1 and spp >= 16 * demo.DISPLAY_SPP and spent <= 2.0 and image.mean() > 0
