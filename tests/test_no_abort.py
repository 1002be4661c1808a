"""No process abort: every integrator of the package renders a scene of every kind of
emitter Mitsuba has (after Mitsuba's own various-emitters test scene: area lights plain and
textured on a rectangle and on a mesh, a sphere light, point, spot, textured spot,
projector, environment map, directional; every surface sharing one white BSDF, as there),
with and without a mirror, in a fresh process each time, and either renders a finite image
or refuses with a Python exception whose first line names the plugin. Dr.Jit aborting the
process (LLVM's "invalid redefinition of function", exit 134) or any other death of the
process fails the test.

Test of the test: the reduced case (a bitmap-textured area light on a mesh, one BSDF for
every surface) aborts the process when Mitsuba's lazily built uv-space scene is not made
before the render (``mi_plugins.light.sources.build_parameterizations`` turned off), and the harness
calls that a failure.
"""
import json
import subprocess
import sys

import pytest

from conftest import REPO

PRELUDE = r'''
import json, sys, numpy as np, mitsuba as mi
mi.set_variant("llvm_ad_rgb")
import mi_plugins
T = mi.ScalarTransform4f
rng = np.random.default_rng(0)
def tex(seed):
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.random.default_rng(seed).random((8, 8, 3)).astype(np.float32))}
def scene(mirror):
    white = {"type": "diffuse", "id": "white", "reflectance": 1.0}
    d = {"type": "scene", "white": white,
         "sensor": {"type": "perspective", "fov": 70, "fov_axis": "x",
                    "to_world": T().look_at(origin=[0, 5, -25], target=[0, 1.3, 0], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": 32, "height": 8, "rfilter": {"type": "box"}}},
         "floor": {"type": "rectangle", "bsdf": {"type": "ref", "id": "white"},
                   "to_world": T().rotate([1, 0, 0], 90).rotate([0, 1, 0], 180).scale([20, 3, 1])},
         "back": {"type": "rectangle", "bsdf": {"type": "ref", "id": "white"},
                  "to_world": T().translate([0, 0, 3]).rotate([0, 1, 0], 180).scale([20, 3, 1])},
         "panel": {"type": "rectangle", "bsdf": {"type": "ref", "id": "white"},
                   "to_world": T().translate([10, 2, 0]).rotate([1, 0, 0], 110).scale(2),
                   "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [0.2, 0.4, 0.6]}}},
         "textured_panel": {"type": "rectangle", "bsdf": {"type": "ref", "id": "white"},
                            "to_world": T().translate([4, 2, 0]).rotate([1, 0, 0], 110).scale(2),
                            "emitter": {"type": "area", "radiance": tex(1)}},
         "textured_cube": {"type": "cube", "bsdf": {"type": "ref", "id": "white"},
                           "to_world": T().translate([-2, 0.5, 2]).scale(0.5),
                           "emitter": {"type": "area", "radiance": tex(2)}},
         "bulb": {"type": "sphere", "center": [7, 1, 1], "radius": 0.4, "bsdf": {"type": "ref", "id": "white"},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 2.0}}},
         "spot": {"type": "spot", "intensity": 15.0, "cutoff_angle": 30, "beam_width": 15,
                  "to_world": T().look_at(origin=[0, 3, 0], target=[0, 0, 0], up=[0, 0, 1])},
         "textured_spot": {"type": "spot", "intensity": 30.0, "texture": tex(3), "cutoff_angle": 30,
                           "beam_width": 15, "to_world": T().look_at(origin=[-4, 3, 0], target=[-4, 0, 0], up=[0, 0, 1])},
         "projector": {"type": "projector", "scale": 15.0, "irradiance": tex(4),
                       "to_world": T().look_at(origin=[-8, 6, 0], target=[-8, 0, 0], up=[0, 0, 1])},
         "point": {"type": "point", "intensity": 5.0, "position": [-14, 2, 0]},
         "sky": {"type": "envmap", "bitmap": mi.Bitmap(np.full((8, 16, 3), 0.05, np.float32)), "scale": 1.0},
         "sun": {"type": "directional", "direction": [0.3, -1, 0.2], "irradiance": 0.5}}
    if mirror:
        d["mirror"] = {"type": "sphere", "center": [2, 1, 1], "radius": 0.8, "bsdf": {"type": "conductor"}}
    return d
def first_line(error):
    return str(error).splitlines()[0] if str(error) else type(error).__name__
'''

RUN = PRELUDE + r'''
for mirror in (False, True):
    for integ in INTEGRATORS:
        label = "%s%s" % (json.dumps(integ, sort_keys=True), " + mirror" if mirror else "")
        print(json.dumps({"start": label}), flush=True)
        try:
            image = np.array(mi.render(mi.load_dict(scene(mirror)), integrator=mi.load_dict(integ), spp=4))
            out = {"label": label, "finite": bool(np.all(np.isfinite(image))), "mean": float(image.mean())}
        except Exception as e:
            out = {"label": label, "refused": first_line(e), "plugin": integ["type"]}
        print(json.dumps(out), flush=True)
'''

#: every integrator of the package, small settings, and a display of a solution
INTEGRATORS = [
    {"type": "stochastic_ray", "max_depth": 4, "iterations": 8, "burn_in": 4},
    {"type": "qmc_lighttrace", "max_depth": 4, "samples": 4000},
    {"type": "qmc_lighttrace", "max_depth": 4, "samples": 4000, "display": "smooth"},
    {"type": "ray_bundle", "max_depth": 4, "iterations": 4, "burn_in": 2, "chains": 4, "resolution": 8},
]


def run_script(code):
    """(exit code, the JSON records printed, stderr's tail) of ``code`` in a fresh interpreter."""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=900)
    records = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    return proc.returncode, records, proc.stderr[-2000:]


def failures(code, records, stderr):
    """What is wrong with a run: a process that did not exit normally (naming the render it
    died in), a render that gave a non-finite image, a refusal that does not name its plugin."""
    out = []
    if code != 0:
        started = [r["start"] for r in records if "start" in r]
        out.append("the process ended with exit code %d during %s: %s"
                   % (code, started[-1] if started else "start-up", stderr[-400:]))
    for r in records:
        if "finite" in r and not r["finite"]:
            out.append("%s: a non-finite image" % r["label"])
        if "refused" in r and not r["refused"].startswith(r["plugin"] + ":"):
            out.append("%s: refused without naming the plugin: %s" % (r["label"], r["refused"]))
    return out


@pytest.mark.slow
def test_every_emitter_with_every_integrator_in_a_fresh_process():
    code, records, stderr = run_script("INTEGRATORS = %r\n%s" % (INTEGRATORS, RUN))
    assert not failures(code, records, stderr), failures(code, records, stderr)
    done = [r for r in records if "label" in r]
    assert len(done) == 2 * len(INTEGRATORS), records
    rendered = [r for r in done if "finite" in r]
    assert len(rendered) >= len(INTEGRATORS), records      # the scene without the mirror renders with all


REDUCED = PRELUDE + r'''
from mi_plugins.light import sources as lights
if OFF:
    lights.build_parameterizations = lambda scene: None
d = {"type": "scene", "sensor": scene(False)["sensor"],
     "floor": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 1.0},
               "to_world": T().rotate([1, 0, 0], 90).rotate([0, 1, 0], 180).scale([20, 3, 1])},
     "lamp": {"type": "cube", "to_world": T().translate([4, 0.5, 2]).scale(0.5),
              "bsdf": {"type": "diffuse", "reflectance": 1.0}, "emitter": {"type": "area", "radiance": tex(0)}}}
print(json.dumps({"start": "stochastic_ray on a textured mesh light"}), flush=True)
image = np.array(mi.render(mi.load_dict(d), integrator=mi.load_dict({"type": "stochastic_ray", "iterations": 4,
                                                                      "burn_in": 2}), spp=2))
print(json.dumps({"label": "reduced", "finite": bool(np.all(np.isfinite(image))), "mean": float(image.mean())}))
'''


def test_textured_mesh_light_renders_and_aborts_without_the_guard():
    code, records, stderr = run_script("OFF = False\n" + REDUCED)
    assert not failures(code, records, stderr), failures(code, records, stderr)
    code, records, stderr = run_script("OFF = True\n" + REDUCED)
    found = failures(code, records, stderr)
    assert code != 0 and found and "during stochastic_ray on a textured mesh light" in found[0], (code, stderr)
