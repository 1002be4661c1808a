"""The solution viewer (``mi_plugins.solution.viewer``): its camera against Mitsuba's sensors, its
page in a real headless Chromium against Mitsuba's ``baked`` display of the same camera,
its refusals and ``mi-plugins view``.

The browser tests need Chromium (``.ci/ensure_browser.sh`` installs Debian's); without
one they skip, saying so. The page's screenshot matches the baked render when every
channel's mean is within ``MEAN_TOLERANCE`` and the pixel values correlate above
``MIN_CORRELATION``; the tests of the test: a camera turned by 3 degrees, a mirrored
camera, colours 10 % too bright, a page with a script error and one with a shader error.
Also: a lamp a hair below a ceiling keeps its pixels; the walkthrough's controls.
"""
import copy
import math
import os

import mitsuba as mi
import numpy as np
import pytest

import budget
import mi_plugins
from browser import Browser, find_browser
from mi_plugins.solution import viewer
from mi_plugins.solution.solution import SolutionMismatch
from mi_plugins.solution.export import baked_shapes
from mi_plugins.solution.viewer_camera import project, sensor_camera

T = mi.ScalarTransform4f
MEAN_TOLERANCE, MIN_CORRELATION = 0.02, 0.9
SIZE = 64


def _other_sensor():
    """A second view of the Cornell box: a wide film, fov along y, a principal point offset
    and a mirrored frame (left and right swapped)."""
    return {"type": "perspective", "fov": 30, "fov_axis": "y", "principal_point_offset_x": 0.05,
            "principal_point_offset_y": -0.04,
            "to_world": T().scale([-1, 1, 1]) @ T().look_at(origin=[0.6, 0.3, 3.6], target=[0, -0.1, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 48, "height": 32, "rfilter": {"type": "box"}}}


@pytest.fixture(scope="module")
def cornell():
    """(scene, integrator, solution) of the Cornell box at 64 x 64 px (box filter), a short
    qmc_lighttrace solve displayed 'baked'."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=SIZE, height=SIZE, rfilter={"type": "box"})
    d["other"] = _other_sensor()
    scene = mi.load_dict(d)
    integ = mi.load_dict({"type": "qmc_lighttrace", "display": "baked", "samples": 20000})
    return scene, integ, mi_plugins.solve(scene, integ, seed=budget.seed(60))


@pytest.fixture(scope="module")
def browser():
    binary = find_browser()
    if binary is None:
        pytest.skip("no Chromium found (MI_PLUGINS_BROWSER, chromium, chromium-browser, google-chrome): "
                    "run .ci/ensure_browser.sh (Debian: apt-get install chromium) for the viewer's browser tests")
    b = Browser(binary)
    yield b
    b.close()


def _srgb8(image):
    """Mitsuba's 8-bit sRGB conversion (the package's PNG writer)."""
    bitmap = mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32), mi.Bitmap.PixelFormat.RGB)
    return np.array(bitmap.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True), dtype=float)


def _show(browser, tmp_path, info, payload, size, name="page"):
    """(page, screenshot as float RGB) of the page of (info, payload) without its overlay."""
    path = tmp_path / (name + ".html")
    path.write_text(viewer.render_page(info, payload))
    page = browser.open("file://%s#test" % path, *size)
    (tmp_path / (name + ".png")).write_bytes(page.png)
    return page, np.array(mi.Bitmap(str(tmp_path / (name + ".png"))), dtype=float)[..., :3]


def _match(shot, reference):
    """(each channel's relative mean difference, correlation of the pixel values)."""
    relative = shot.mean(axis=(0, 1)) / reference.mean(axis=(0, 1)) - 1
    return relative, float(np.corrcoef(shot.ravel(), reference.ravel())[0, 1])


def _matches(page, shot, reference):
    relative, correlation = _match(shot, reference)
    return page.ok and np.abs(relative).max() < MEAN_TOLERANCE and correlation > MIN_CORRELATION


@pytest.fixture(scope="module")
def baked(cornell):
    """Mitsuba's baked display of both sensors (16 samples a pixel), 8-bit sRGB."""
    scene, integ, _ = cornell
    return [_srgb8(mi.render(scene, sensor=k, integrator=integ, spp=16, seed=budget.seed(60))) for k in (0, 1)]


# ------------------------------------------------------------------ the page against the baked display
@pytest.mark.parametrize("sensor", [0, 1])
def test_the_page_shows_the_baked_display_of_the_sensor(cornell, baked, browser, tmp_path, sensor):
    scene, integ, solution = cornell
    info, payload = viewer.page_data(solution, scene, sensor)
    page, shot = _show(browser, tmp_path, info, payload, (info["camera"]["width"], info["camera"]["height"]))
    assert page.title == "ready" and not page.errors, (page.title, page.errors)
    relative, correlation = _match(shot, baked[sensor])
    print("sensor %d: channel means %s %%, correlation %.4f" % (sensor, np.round(100 * relative, 2), correlation))
    assert np.abs(relative).max() < MEAN_TOLERANCE and correlation > MIN_CORRELATION
    assert integ.solve_count == 1           # the renders displayed the solution the page shows


def _turned(info, degrees):
    out = copy.deepcopy(info)
    k, a = np.array(info["camera"]["up"]), math.radians(degrees)
    out["camera"]["axes"] = [(np.array(v) * math.cos(a) + np.cross(k, v) * math.sin(a)
                              + k * np.dot(k, v) * (1 - math.cos(a))).tolist() for v in info["camera"]["axes"]]
    return out


def _brighter(info, payload, factor):
    s = info["layout"]["front"]
    front = np.frombuffer(payload, np.float16, s["count"], s["offset"]) * factor
    return payload[:s["offset"]] + front.astype(np.float16).tobytes() + payload[s["offset"] + 2 * s["count"]:]


def test_a_wrong_camera_or_wrong_colours_fail_the_comparison(cornell, baked, browser, tmp_path):
    """Test of the test (the right page passes above): a camera turned by 3 degrees, a
    mirrored camera, colours 10 % too bright."""
    scene, _, solution = cornell
    info, payload = viewer.page_data(solution, scene)
    mirrored = copy.deepcopy(info)
    mirrored["camera"]["axes"][0] = [-v for v in info["camera"]["axes"][0]]
    mirrored["camera"]["mirrored"] = True
    for name, (i, p) in {"turned": (_turned(info, 3), payload), "mirrored": (mirrored, payload),
                         "brighter": (info, _brighter(info, payload, 1.1))}.items():
        page, shot = _show(browser, tmp_path, i, p, (SIZE, SIZE), name)
        assert page.ok, (name, page.errors)
        assert not _matches(page, shot, baked[0]), name


def test_a_page_error_is_reported(cornell, baked, browser, tmp_path):
    """A script error and a shader that does not compile end as errors (title and console),
    and such a page fails the comparison whatever its pixels."""
    scene, _, solution = cornell
    info, payload = viewer.page_data(solution, scene)
    text = viewer.render_page(info, payload)
    broken = {"script": text.replace("    layout();\n    gl.finish();", "    layout();\n    null.x;"),
              "shader": text.replace("gl_Position = clip * vec4(position, 1.0);", "gl_Position = clip * position;")}
    for name, page_text in broken.items():
        assert page_text != text, name
        path = tmp_path / (name + ".html")
        path.write_text(page_text)
        page = browser.open("file://%s#test" % path, SIZE, SIZE)
        assert page.title.startswith("error") and page.errors and not page.ok, (name, page.title, page.errors)
        assert not _matches(page, baked[0], baked[0]), name


def test_a_lamp_a_hair_below_the_ceiling_keeps_its_pixels(browser, tmp_path):
    """The Cornell box's lamp 0.1 mm below its ceiling, at 128 px: every pixel Mitsuba shows
    white is white on the page (the emitters' polygon offset). Test of the test: without
    the offset the ceiling takes some (measured: 36 of 110)."""
    d = mi.cornell_box()
    d["sensor"]["film"].update(width=128, height=128, rfilter={"type": "box"})
    d["light"]["to_world"] = T().translate([0, 1 - 1e-4, 0.01]) @ T().rotate([1, 0, 0], 90) @ T().scale([0.23, 0.19, 0.19])
    scene = mi.load_dict(d)
    integ = mi.load_dict({"type": "qmc_lighttrace", "display": "baked", "samples": 5000})
    solution = mi_plugins.solve(scene, integ, seed=budget.seed(63))
    lamp = _srgb8(mi.render(scene, integrator=integ, spp=4, seed=budget.seed(63))).min(axis=2) >= 254
    info, payload = viewer.page_data(solution, scene)
    text = viewer.render_page(info, payload)
    lost = {}
    for name, page_text in {"offset": text, "none": text.replace("gl.polygonOffset(-1, -1)", "gl.polygonOffset(0, 0)")}.items():
        (tmp_path / "lamp.html").write_text(page_text)
        page = browser.open("file://%s#test" % (tmp_path / "lamp.html"), 128, 128)
        (tmp_path / "lamp.png").write_bytes(page.png)
        shot = np.array(mi.Bitmap(str(tmp_path / "lamp.png")), dtype=float)[..., :3]
        assert page.ok, page.errors
        lost[name] = int((shot.min(axis=2)[lamp] < 250).sum())
    print("lamp pixels %d, lost %s" % (lamp.sum(), lost))
    assert lamp.sum() > 50 and lost["offset"] == 0 and lost["none"] > 10, (int(lamp.sum()), lost)


def test_the_walkthrough_moves_turns_resets_and_exposes(cornell, browser, tmp_path):
    """W moves (a tap alone moves one step: mean pixel change 3.5 of 255), a drag turns, R
    goes back to the sensor (the same pixels), + raises the exposure; the overlay shows
    without #test and the page stays free of errors."""
    scene, _, solution = cornell
    path = solution.to_html(str(tmp_path / "walk.html"), scene)
    page = browser.open("file://%s" % path, 256, 256)
    assert page.ok and browser.evaluate("getComputedStyle(document.getElementById('help')).display") != "none"
    browser.open("file://%s#test" % path, SIZE, SIZE)

    def image():
        (tmp_path / "s.png").write_bytes(browser.screenshot())
        return np.array(mi.Bitmap(str(tmp_path / "s.png")), dtype=float)[..., :3]
    start = image()
    browser.press("KeyW", "w", hold=0.1)
    moved = image()
    browser.press("KeyR", "r")
    assert np.array_equal(image(), start)
    browser.drag((32, 32), (44, 30))
    turned = image()
    browser.press("KeyR", "r")
    browser.press("Equal", "+")
    brighter = image()
    assert np.abs(moved - start).mean() > 2 and np.abs(turned - start).mean() > 2
    assert brighter.mean() > start.mean() + 5
    assert browser.evaluate("document.title") == "ready"


# ------------------------------------------------------------------ the camera, the file, refusals
SENSORS = {
    "look_at": {"type": "perspective", "fov": 40, "to_world": T().look_at([1, 2, 3], [0, 0, 0], [0, 1, 0])},
    "fov_y_offset": {"type": "perspective", "fov": 35, "fov_axis": "y", "principal_point_offset_x": 0.1,
                     "principal_point_offset_y": -0.2, "to_world": T().look_at([1, 2, 3], [0, 0, 0], [0, 0, 1])},
    "mirrored_diagonal": {"type": "perspective", "fov": 50, "fov_axis": "diagonal",
                          "to_world": T().scale([-1, 1, 1]) @ T().look_at([-2, 1, 3], [0, 0, 0], [0, 1, 0])},
    "thinlens": {"type": "thinlens", "fov": 40, "aperture_radius": 1e-7,
                 "to_world": T().look_at([1, 2, 3], [0, 0, 0], [0, 1, 0])},
}


@pytest.mark.parametrize("name", SENSORS)
def test_the_camera_projects_as_the_sensor_traces(name):
    """Points along the sensor's rays through random film positions project back to those
    positions; test of the test: the projection with 2 % more focal length misses them."""
    sensor = dict(SENSORS[name], film={"type": "hdrfilm", "width": 48, "height": 30})
    scene = mi.load_dict({"type": "scene", "sensor": sensor})
    camera = sensor_camera(scene)
    position = budget.rng(61).random((64, 2))
    ray, _ = scene.sensors()[0].sample_ray(0.0, 0.0, mi.Point2f(position[:, 0], position[:, 1]), mi.Point2f(0.5))
    points = np.array(ray.o, dtype=np.float64).T + 2.5 * np.array(ray.d, dtype=np.float64).T
    assert np.abs(project(camera, points)[0] - position).max() < 1e-5
    assert camera["mirrored"] == (name == "mirrored_diagonal")
    wrong = dict(camera, c=camera["c"] * 1.02)
    assert np.abs(project(wrong, points)[0] - position).max() > 1e-3


def test_the_page_is_self_contained_and_small(cornell, tmp_path):
    scene, _, solution = cornell
    path = solution.to_html(str(tmp_path / "room.html"), scene, exposure=-1.5)
    text = open(path, encoding="utf-8").read()
    assert "http://" not in text and "https://" not in text and " src=" not in text and "<link" not in text
    assert '"exposure":-1.5' in text and os.path.getsize(path) < 200e3
    info, _ = viewer.page_data(solution, scene)
    assert info["triangles"] == sum(len(faces) for _, _, faces, _, _ in baked_shapes(solution))


def test_what_the_page_cannot_show_is_said():
    """A constant sky is the background colour; a glossy shape is counted in the overlay's
    notes; an environment map is said to be black."""
    from test_solution import _floor_scene
    glossy = {"type": "sphere", "radius": 0.2, "to_world": T().translate([0, 0.3, 0]), "bsdf": {"type": "roughconductor"}}
    scene = _floor_scene("rectangle", {"sky": {"type": "constant", "radiance": {"type": "rgb", "value": [0.2, 0.3, 0.4]}},
                                       "ball": glossy})
    info, _ = viewer.page_data(mi_plugins.solve(scene, {"type": "qmc_lighttrace", "samples": 2000}, seed=budget.seed(64)),
                               scene)
    assert np.allclose(info["background"], [0.2, 0.3, 0.4]) and info["notes"] == [
        "1 of 3 shapes are not purely diffuse: they show their emission only"]
    assert viewer._background(mi.load_dict({"type": "scene", "sky": {"type": "envmap", "bitmap": mi.Bitmap(
        np.ones((8, 16, 3), dtype=np.float32))}}))[1] == "the environment (EnvironmentMapEmitter) is not shown: black background"


def test_bad_input_is_refused_by_name(cornell, tmp_path):
    scene, _, solution = cornell
    out = str(tmp_path / "x.html")
    with pytest.raises(ValueError, match=r"Solution.to_html: sensor 2; valid range: 0 \.\. 1"):
        solution.to_html(out, scene, sensor=2)
    for bad in (float("nan"), 30.0, True):
        with pytest.raises(ValueError, match=r"Solution.to_html: exposure .*valid range: -20 \.\. 20"):
            solution.to_html(out, scene, exposure=bad)
    ortho = mi.load_dict({"type": "scene", "s": {"type": "orthographic"}, "floor": {"type": "rectangle"}})
    with pytest.raises(ValueError, match="sensor 0 is a OrthographicCamera; the viewer starts from a 'perspective'"):
        sensor_camera(ortho)
    with pytest.raises(SolutionMismatch):
        solution.to_html(out, ortho)
    assert not os.path.exists(out)


def test_mi_plugins_view_writes_the_page_of_a_saved_solution(tmp_path, capsys):
    from mi_plugins.app import cli
    xml = tmp_path / "floor.xml"
    xml.write_text('<scene version="3.0.0"><integrator type="qmc_lighttrace"><integer name="samples" value="2000"/>'
                   '</integrator><sensor type="perspective"><float name="fov" value="45"/><transform name="to_world">'
                   '<lookat origin="0, 2.5, 2.5" target="0, 0, 0" up="0, 1, 0"/></transform><film type="hdrfilm">'
                   '<integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>'
                   '<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/></transform></shape>'
                   '<emitter type="point"><point name="position" x="0" y="1" z="0"/></emitter></scene>')
    scene = mi.load_file(str(xml))
    mi_plugins.solve(scene, seed=budget.seed(62)).save(str(tmp_path / "floor.npz"))
    out = tmp_path / "floor.html"
    assert cli.main(["view", str(tmp_path / "floor.npz"), "--scene", str(xml), "-o", str(out)]) == 0
    assert "wrote %s" % out in capsys.readouterr().out and "DecompressionStream" in out.read_text()
    assert cli.main(["view", str(tmp_path / "floor.npz"), "--scene", str(xml), "-o", str(tmp_path / "a.png")]) == 2
    assert "must end in .html" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path / "none.npz"), "--scene", str(xml), "-o", str(out)]) == 2
    assert "solution file" in capsys.readouterr().err
