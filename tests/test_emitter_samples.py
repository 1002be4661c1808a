"""Further camera rays for the emission seen directly (``emitter_samples`` of every display
of ``qmc_lighttrace`` and ``ray_bundle``, integrators.display.edge_pixels): the image keeps
its mean, with a box or a Gaussian filter, under an area light or an environment, through
other cameras and films; the lamp's edge pixels are far less noisy; nothing is traced
where no emitter edge is seen; ``ray_bundle``'s frozen camera pass records them once."""
import os

import mitsuba as mi
import numpy as np
import pytest

from conftest import REPO, run_python

from mi_plugins.solution import display

T = mi.ScalarTransform4f
SEEDS = (1, 2, 3)


def lamp_scene(rfilter="box", sky=False):
    """A lamp (a square facing the camera, its edges across pixels) above a floor it lights,
    a dark back wall; or (``sky``) a black block alone in front of a bright environment."""
    d = {"type": "scene",
         "floor": {"type": "rectangle", "to_world": T().translate([0, -1, 0]).rotate([1, 0, 0], -90).scale(2),
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}},
         "wall": {"type": "rectangle", "to_world": T().translate([0, 0, -2]).scale(2),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.1, 0.1, 0.1]}}},
         "sensor": {"type": "perspective", "fov": 50,
                    "to_world": T().look_at(origin=[0.03, 0.02, 3.0], target=[0.03, 0.02, 0], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": rfilter}}}}
    if sky:
        d["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": [2.0, 2.0, 2.0]}}
        d["block"] = {"type": "cube", "to_world": T().rotate([0, 0, 1], 20).scale(0.45),
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}}
        del d["wall"], d["floor"]
    else:
        d["lamp"] = {"type": "rectangle", "to_world": T().rotate([0, 0, 1], 15).scale(0.43),
                     "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [5.0, 5.0, 5.0]}}}
    return mi.load_dict(d)


def renders(scene, emitter_samples, spp=64, mode="smooth"):
    integrator = mi.load_dict({"type": "qmc_lighttrace", "display": mode, "samples": 20000,
                               "emitter_samples": emitter_samples})
    return np.stack([np.array(mi.render(scene, integrator=integrator, spp=spp, seed=s))[..., :3] for s in SEEDS])


def agree(a, b, radiance, spp=64, bound=4.5):
    """Per pixel, the two sets of renders' means differ by less than ``bound`` standard
    errors: from the renders' spread, and at least the coverage noise of a pixel that sees
    an emitter of ``radiance`` over a share c = mean / radiance of it (radiance^2 c (1 - c)
    per camera sample): a pixel that a lamp's corner barely touches can show it in none
    of a few renders, and their spread is then 0."""
    c = np.clip(np.concatenate([a, b]).mean(axis=0) / radiance, 0.0, 1.0)
    floor = radiance ** 2 * c * (1 - c) / (spp * len(a))
    se = np.sqrt(np.maximum(a.var(axis=0, ddof=1) / len(a), floor) + np.maximum(b.var(axis=0, ddof=1) / len(b), floor))
    return np.all(np.abs(a.mean(axis=0) - b.mean(axis=0)) <= bound * se + 1e-4)


@pytest.mark.parametrize("rfilter,sky,mode", [("box", False, "smooth"), ("gaussian", False, "baked"),
                                              ("box", True, "smooth"), ("box", False, "gather")])
def test_the_mean_stays_and_the_edges_quieten(rfilter, sky, mode):
    scene = lamp_scene(rfilter, sky)
    one, eight = renders(scene, 1, mode=mode), renders(scene, 8, mode=mode)
    assert agree(one, eight, 2.0 if sky else 5.0)
    # the pixels that the emitter's edge crosses (partly covered): their noise falls well
    # beyond 8 fold with a box filter (a Gaussian one mixes in its neighbours' other noise)
    seen = np.array(mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 1}), spp=1024))
    c = seen[..., :3].mean(axis=-1) / (2.0 if sky else 5.0)          # the share of the pixel that sees emission
    edge = (c > 0.03) & (c < 0.97)
    assert edge.sum() >= 8
    ratio = one.var(axis=0, ddof=1).mean(axis=-1)[edge].sum() / eight.var(axis=0, ddof=1).mean(axis=-1)[edge].sum()
    assert ratio > (4.0 if rfilter == "gaussian" else 8.0), ratio


@pytest.mark.parametrize("rfilter", ["box", "gaussian"])
def test_a_wrong_share_is_caught(rfilter, monkeypatch):
    """Test of the test: the main ray's emission kept at full weight beside the further
    rays' shares (the lamp's edges too bright), or the shares splatted one pixel off; with
    a box filter (the camera block's weight-0 shares) and a Gaussian one (a block of its
    own)."""
    scene = lamp_scene(rfilter)
    one = renders(scene, 1)
    keep = display.emission_shares
    monkeypatch.setattr(display, "emission_shares", lambda *a: keep(*a) * 0.0)
    assert not agree(one, renders(scene, 8), 5.0)

    class Off:
        def __init__(self, frame):
            self.frame = frame

        def __getattr__(self, name):
            return getattr(self.frame, name)

        def put_emission(self, pos, value, weight, active=True):
            self.frame.put_emission(pos + mi.Vector2f(1.0, 0.0), value, weight, active)

        def put_camera_share(self, pos, value, active=True, name="camera"):
            self.frame.put_camera_share(pos + mi.Vector2f(1.0, 0.0), value, active, name)

    monkeypatch.setattr(display, "emission_shares", lambda frame, *a: keep(Off(frame), *a))
    assert not agree(one, renders(scene, 8), 5.0)
    monkeypatch.setattr(display, "emission_shares", keep)
    assert agree(one, renders(scene, 8), 5.0)


def test_nothing_is_traced_where_no_emitter_is_seen(monkeypatch):
    """No emitter in view (the camera turned to the floor), ``hide_emitters`` or
    ``emitter_samples`` 1: no further rays; the edge pixels are the ones next to the lamp."""
    calls = []
    keep = display.emission_shares
    monkeypatch.setattr(display, "emission_shares", lambda *a: calls.append(1) or keep(*a))
    scene = lamp_scene()
    integrator = mi.load_dict({"type": "qmc_lighttrace", "display": "smooth", "samples": 5000})
    mi.render(scene, integrator=integrator, spp=4)
    assert calls
    calls.clear()
    down = mi.load_dict({"type": "perspective", "fov": 20, "film": {"type": "hdrfilm", "width": 8, "height": 8},
                         "to_world": T().look_at(origin=[1.5, 0, 1.5], target=[1.5, -1, 1.5], up=[0, 0, 1])})
    mi.render(scene, integrator=integrator, sensor=down, spp=4)
    for params in ({"hide_emitters": True}, {"emitter_samples": 1}):
        mi.render(scene, integrator=mi.load_dict({"type": "qmc_lighttrace", "display": "smooth", "samples": 5000,
                                                  **params}), spp=4)
    assert not calls


def test_the_edge_pixels_follow_the_lamps_edges():
    """The pixels that take further rays: every pixel the lamp's edge crosses, none more
    than a pixel away from one (the lamp's inside and the floor take none); a
    constant-radiance scene (every surface emits alike) takes none."""
    from mi_plugins.render.frame import Frame
    scene = lamp_scene()
    frame = Frame(scene, scene.sensors()[0], 1, 0, "test")
    shifts, mask, pixels = display.edge_pixels(frame, -1, False, 8)
    mask = np.array(mask).reshape(16, 16)
    seen = np.array(mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 1}), spp=1024))
    c = seen[..., :3].mean(axis=-1) / 5.0
    crossed = (c > 0.01) & (c < 0.99)
    near = crossed.copy()
    for axis in (0, 1):
        for step in (1, -1):
            near |= np.roll(crossed, step, axis=axis)
    near |= np.roll(np.roll(crossed, 1, 0), 1, 1) | np.roll(np.roll(crossed, -1, 0), -1, 1) | \
        np.roll(np.roll(crossed, 1, 0), -1, 1) | np.roll(np.roll(crossed, -1, 0), 1, 1)
    assert crossed.sum() >= 8 and np.all(mask[crossed]) and not np.any(mask & ~near)
    assert np.any((c >= 0.99) & ~mask)                            # inside the lamp: nothing to add
    assert len(shifts) == 8 and len({x for x, _ in shifts}) == 8 and len({y for _, y in shifts}) == 8
    keller = mi.load_file(os.path.join(REPO, "configs", "keller_cube.xml"), integrator="qmc_lighttrace")
    assert display.edge_pixels(Frame(keller, keller.sensors()[0], 1, 0, "test"), -1, False, 8) is None


def test_an_undeveloped_film_keeps_its_alpha():
    """``render(..., develop=False)`` leaves the film holding the sum of the camera blocks
    (with a Gaussian filter the emission's own among them): its alpha is the camera rays' coverage, as
    in the developed image (a block of unit weights set it to 1 before)."""
    scene = lamp_scene(sky=False)
    sensor = mi.load_dict({"type": "perspective", "fov": 70, "film": {"type": "hdrfilm", "width": 16, "height": 16,
                                                                       "pixel_format": "rgba",
                                                                       "rfilter": {"type": "gaussian"}},
                           "to_world": T().look_at(origin=[0, 0.5, 3.0], target=[0, 0.3, 0], up=[0, 1, 0])})
    integrator = mi.load_dict({"type": "qmc_lighttrace", "display": "smooth", "samples": 5000})
    image = np.array(mi.render(scene, integrator=integrator, sensor=sensor, spp=16, seed=2))
    integrator.render(scene, sensor, seed=2, spp=16, develop=False)
    held = np.array(sensor.film().develop())
    alpha = image[..., 3]
    assert alpha.min() < 0.5 and alpha.max() == 1.0          # the wall ends: rays leave the scene
    np.testing.assert_allclose(held, image, rtol=1e-5, atol=1e-6)


def test_other_cameras_and_films_keep_the_mean(monkeypatch):
    """A thin lens (the further rays share the sample's aperture point), a crop window, a
    film that samples its border, a tent filter and a one-channel film: the mean as with
    one ray per sample."""
    scene = lamp_scene()
    sensor = mi.load_dict({"type": "thinlens", "fov": 50, "aperture_radius": 0.05, "focus_distance": 3.0,
                           "to_world": T().look_at(origin=[0.03, 0.02, 3.0], target=[0.03, 0.02, 0], up=[0, 1, 0]),
                           "film": {"type": "hdrfilm", "width": 24, "height": 24, "crop_offset_x": 4,
                                    "crop_offset_y": 4, "crop_width": 16, "crop_height": 16, "sample_border": True,
                                    "pixel_format": "luminance", "rfilter": {"type": "tent"}}})

    def runs(count):
        integrator = mi.load_dict({"type": "qmc_lighttrace", "display": "smooth", "samples": 20000,
                                   "emitter_samples": count})
        return np.stack([np.array(mi.render(scene, integrator=integrator, sensor=sensor, spp=64, seed=s))
                         for s in SEEDS])
    calls, keep = [], display.emission_shares
    monkeypatch.setattr(display, "emission_shares", lambda *a: calls.append(1) or keep(*a))
    one, eight = runs(1), runs(8)
    assert len(calls) == len(SEEDS) and one.shape[1:3] == (16, 16) and np.any(one > 1.0)
    assert agree(one, eight, 5.0)


def test_ray_bundle_gather_takes_them_in_its_frozen_camera_pass(monkeypatch):
    """``ray_bundle``'s gather (its camera passes are frozen steps): the mean as with one
    ray, the edge pixels quieter, and the replay's image the plain (traced) render's."""
    from mi_plugins.integrators.ray_bundle import frozen
    scene = lamp_scene()

    def runs(count, seeds=SEEDS):
        integrator = mi.load_dict({"type": "ray_bundle", "iterations": 12, "emitter_samples": count})
        return integrator, np.stack([np.array(mi.render(scene, integrator=integrator, spp=1, seed=s))[..., :3]
                                     for s in seeds])
    _, one = runs(1)
    integrator, eight = runs(8)
    assert agree(one, eight, 5.0)
    seen = np.array(mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 1}), spp=1024))
    edge = (seen[..., :3].mean(axis=-1) > 0.15) & (seen[..., :3].mean(axis=-1) < 4.85)
    assert one.var(axis=0, ddof=1)[edge].sum() > 8.0 * eight.var(axis=0, ddof=1)[edge].sum()
    monkeypatch.setattr(frozen, "ENABLED", False)
    _, plain = runs(8, SEEDS[:1])
    np.testing.assert_allclose(plain[0], eight[0], rtol=1e-4, atol=1e-5)


def test_ray_bundle_records_its_camera_pass_once_with_emitter_samples():
    """The camera pass of ``ray_bundle``'s gather with ``emitter_samples`` is recorded once
    and replayed by the next renders. In a fresh process: after some hundreds of other
    renders in one process, Dr.Jit 1.5.0 has been seen to refuse recordings of steps it
    recorded in a fresh process ("record(): error encountered while recording a frozen
    function"; the renders fall back to plain steps, same image), which this test is not
    about."""
    r = run_python(
        "import numpy as np, mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import mi_plugins, sys\n"
        "sys.path.insert(0, 'tests')\nfrom test_emitter_samples import lamp_scene\n"
        "scene = lamp_scene()\n"
        "integ = mi.load_dict({'type': 'ray_bundle', 'iterations': 12, 'emitter_samples': 8})\n"
        "for seed in (1, 2, 3):\n    mi.render(scene, integrator=integ, spp=1, seed=seed)\n"
        "cache = integ.step_cache\n"
        "print('UNFROZEN', cache.last in cache.unfrozen, cache.errors.get(cache.last))\n"
        "print('RECORDINGS', cache.steps[cache.last + (True,)][1].recordings)\n")
    assert "UNFROZEN False" in r.stdout and "RECORDINGS 1" in r.stdout, r.stdout + r.stderr
