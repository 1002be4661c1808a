"""Seconds per render of `ray_bundle` against Mitsuba's `path`, in the same process.

Scenes (all built by the package, nothing to download):

- the coverage matrix's 8-pixel cells (``mi_plugins.verify.coverage``) with the matrix's
  ray_bundle settings and its reference budget for path (512 spp);
- the tests' 16-pixel analytic scenes (the furnace box, the constant-radiance
  light-source box) with the tests' settings;
- the open scene of large white planes and seven emitters (``rows.open_many_emitters``)
  at 128 x 16 pixels, 1 spp, every parameter at its default (``--big``: also 512 x 64
  pixels at 32 spp).

Every line gives the first render (tracing, kernel compilation or the disk cache) and the
mean of the next ``--repeat`` renders (other seeds), for ray_bundle and for path, and
their ratio. Run from the repository root, also against another checkout to compare:

    python3 benchmarks/ray_bundle_speed.py
    PYTHONPATH=/path/to/other/checkout python3 benchmarks/ray_bundle_speed.py --only open
"""
import argparse
import time
import warnings

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401
from mi_plugins.verify import analytic  # noqa: E402
from mi_plugins.verify.coverage import rows as coverage_rows  # noqa: E402

#: the coverage matrix's ray_bundle settings (mi_plugins.verify.coverage.expected.RAY_BUNDLE)
MATRIX = {"type": "ray_bundle", "chains": 16, "resolution": 16, "iterations": 12, "burn_in": 6}
MATRIX_ROWS = ("bsdf:diffuse", "bsdf:plastic", "emitter:spot", "emitter:constant", "shape:sphere",
               "texture:bitmap")
#: the tests' settings (tests/test_ray_bundle.py: rb())
TESTS = {"type": "ray_bundle", "chains": 32, "iterations": 16, "burn_in": 8, "resolution": 16, "subdivide": False,
         "first_shot": False, "average_diffuse": False}


def timed(scene, integrator, spp, repeat):
    """(first render's seconds, mean seconds of ``repeat`` more, image mean)."""
    times, value = [], 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for k in range(repeat + 1):
            t = time.perf_counter()
            img = np.array(mi.render(scene, integrator=integrator, spp=spp, seed=k))
            times.append(time.perf_counter() - t)
            value = float(img.mean())
    return times[0], float(np.mean(times[1:])) if repeat else times[0], value


def line(name, scene, bundle, bundle_spp, path_spp, repeat):
    b = timed(scene, mi.load_dict(bundle), bundle_spp, repeat)
    p = timed(scene, mi.load_dict({"type": "path", "max_depth": bundle.get("max_depth", -1)}), path_spp, repeat)
    print("%-38s %8.3f %8.3f   %8.3f %8.3f   %7.1fx   (means %.4g / %.4g)"
          % (name, b[0], b[1], p[0], p[1], b[1] / max(p[1], 1e-9), b[2], p[2]), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="renders after the first (default 3)")
    ap.add_argument("--only", choices=("matrix", "tests", "open"), help="one group of scenes")
    ap.add_argument("--big", action="store_true", help="also the open scene at 512 x 64 px and 32 spp")
    a = ap.parse_args()
    print("%-38s %17s   %17s   %8s" % ("scene", "ray_bundle: first, next", "path: first, next", "ratio"))
    if a.only in (None, "matrix"):
        table = coverage_rows.all_rows()
        for key in MATRIX_ROWS:
            line("matrix %s (8 px)" % key, mi.load_dict(table[key].build(8)), MATRIX, 1, 512, a.repeat)
    if a.only in (None, "tests"):
        for name, cfg in (("furnace_box", TESTS), ("constant_lightsource_box", {"type": "ray_bundle"})):
            case = analytic.cases()[name](resolution=16)
            line("tests %s (16 px)" % name, case.scene({"type": "path"}), cfg, 1, 64, a.repeat)
    if a.only in (None, "open"):
        for w, spp in ((128, 1),) + (((512, 32),) if a.big else ()):
            d = coverage_rows.open_many_emitters(w // 4)
            d["sensor"]["film"].update(width=w, height=w // 8)
            line("open scene %dx%d, %d spp (defaults)" % (w, w // 8, spp), mi.load_dict(d), {"type": "ray_bundle"},
                 spp, spp, a.repeat)


if __name__ == "__main__":
    main()
