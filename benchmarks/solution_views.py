"""One solve, every view: the view-independent solutions of `ray_bundle` and
`qmc_lighttrace` against Mitsuba's `path`, measured in the same run (docs/solutions.md).

1. **Single view**: the smooth display (solve + display) against `path` at doubling
   budgets on the benchmark's Cornell box (real_scene_meshes.py) at 128 and 256 px and on
   `cornell_closed`; RMSE against a cached long `path` reference, full image and away from
   the visible light, read at an equal time t* (1 s) on each method's curve; the bias of the
   smooth reconstruction alone (a long solve and display, its noise removed).
2. **A camera orbit**: 60 frames along an arc in front of the Cornell box at 128 px. `path`
   renders every frame at 64 spp; a solution integrator solves once and displays every
   frame at the smallest camera sample count whose RMSE on the checked frames (every
   tenth, against cached references) is at most `path`'s at 64 spp, on the full image and
   away from the visible light; total seconds compared (displays `smooth` and `baked`).
3. **First image**: seconds from the loaded scene to the first preview image of a solve.

Run from the repository root (a few minutes with --quick; references cached in
benchmarks/.cache):

    python3 benchmarks/solution_views.py [--quick] [--write-docs] [--parts single,orbit,first]
"""
import argparse
import math
import os
import sys
import time

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401
from mi_plugins.solution import views  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
import real_scene_meshes as rsm  # noqa: E402
from analysis import interp_loglog  # noqa: E402

ROOT = os.path.dirname(HERE)
DOCS = os.path.join(ROOT, "docs", "solutions.md")
CACHE = os.path.join(HERE, ".cache")
#: the solution integrators' settings tried (their solve budgets): each with a ladder of camera samples
METHODS = {
    "ray_bundle": [{"type": "ray_bundle", "display": "smooth", "iterations": it} for it in (16, 32)],
    "qmc_lighttrace": [{"type": "qmc_lighttrace", "display": "smooth", "samples": n} for n in (100000, 400000)],
}
ORBIT_FRAMES = 60
ORBIT_TURNS = 1.0 / 12.0          # an arc of 30 degrees in front of the open box
ORBIT_CHECKED = range(0, ORBIT_FRAMES, 10)
PATH_ORBIT_SPP = 64


def errors(image, ref, ref_var, keep):
    """(RMSE, RMSE away from the light): the reference's own noise removed."""
    e = (image - ref) ** 2
    full = math.sqrt(max(e.mean() - ref_var.mean(), 0.25 * e.mean()))
    away = math.sqrt(max(e[keep].mean() - ref_var[keep].mean(), 0.25 * e[keep].mean()))
    return full, away


def timed(scene, integrator, spp, seed, sensor=0):
    t0 = time.perf_counter()
    image = np.array(mi.render(scene, integrator=integrator, sensor=sensor, spp=int(spp), seed=int(seed)),
                     dtype=np.float64)[..., :3]
    return image, time.perf_counter() - t0


def curve(scene, make, ladder, ref, ref_var, keep, cap):
    """[dict(spp, seconds, rmse, away)] of a fresh integrator ``make()`` per render (so a
    solution integrator solves every time: its solve counts), two seeds per budget."""
    timed(scene, make(), 1, 999)                          # compile
    points = []
    for spp in ladder:
        runs = [timed(scene, make(), spp, seed) for seed in (1, 2)]
        errs = [errors(image, ref, ref_var, keep) for image, _ in runs]
        point = dict(spp=spp, seconds=float(np.mean([s for _, s in runs])),
                     rmse=float(np.sqrt(np.mean([e[0] ** 2 for e in errs]))),
                     away=float(np.sqrt(np.mean([e[1] ** 2 for e in errs]))))
        points.append(point)
        if point["seconds"] > cap:
            break
    return points


def at(points, key, t):
    return interp_loglog([dict(seconds=p["seconds"], rmse=p[key]) for p in points], t)[0]


def single(name, res, quick, say):
    d, _ = rsm.scene_dict(name, res)
    scene = mi.load_dict(d)
    ref, ref_var = rsm.reference(name, res, 1024 if quick else 4096)
    keep = rsm.away_from_light(ref)
    cap = 2.0 if quick else 4.0
    path = curve(scene, lambda: mi.load_dict({"type": "path"}), [4 << k for k in range(12)], ref, ref_var, keep,
                 cap)
    base = at(path, "rmse", 1.0), at(path, "away", 1.0)
    say("\n### %s at %d px (path at 1 s: RMSE %.4f, away from the light %.4f)\n" % (name, res, *base))
    say("| method | settings | RMSE at 1 s | / path | away | / path | points (spp: s, RMSE) |")
    say("|---|---|---|---|---|---|---|")
    for method, configs in METHODS.items():
        for cfg in configs[:1] if quick else configs:
            pts = curve(scene, lambda: mi.load_dict(cfg), [4 << k for k in range(10)], ref, ref_var, keep, cap)
            full, away = at(pts, "rmse", 1.0), at(pts, "away", 1.0)
            settings = ", ".join("%s %s" % (k, v) for k, v in cfg.items() if k not in ("type", "display"))
            say("| %s | %s | %.4f | %.2f | %.4f | %.2f | %s |" % (
                method, settings, full, full / base[0], away, away / base[1],
                " ".join("%d: %.2f s %.4f" % (p["spp"], p["seconds"], p["rmse"]) for p in pts)))


#: the displays tried on the orbit (``baked``: every light from the solution, no rays past
#: the visible point on diffuse surfaces)
ORBIT_METHODS = {
    "ray_bundle": [{"type": "ray_bundle", "display": disp, "iterations": 32} for disp in ("smooth", "baked")],
    "qmc_lighttrace": [{"type": "qmc_lighttrace", "display": disp, "samples": 400000} for disp in ("smooth", "baked")],
}
ORBIT_SPP = (4, 8, 16, 32, 48, 64, 96, 128, 192, 256)   # the fewest that reach path, to within 1.5x


def kept_counts(sampler, counts):
    """The sample counts of ``counts`` that ``sampler`` keeps (``ldsampler``, ``stratified``
    round the others)."""
    return [n for n in counts if mi.load_dict({"type": sampler, "sample_count": n}).sample_count() == n]


def orbit(res, quick, say, sampler="independent"):
    """One solve and every frame displayed, at the fewest camera samples whose worst
    checked frame reaches path's RMSE at PATH_ORBIT_SPP: on the full image, and away from
    the visible light (its edge pixels carry a coverage noise per camera sample that every
    method shares). ``sampler``: the scene's sampler, the same for ``path`` and the
    displays."""
    d, _ = rsm.scene_dict("cornell", res)
    d["sensor"]["sampler"] = {"type": sampler, "sample_count": PATH_ORBIT_SPP}   # a count every sampler keeps
    scene = mi.load_dict(d)
    frames = views.orbit(scene, ORBIT_FRAMES, turns=ORBIT_TURNS)
    refs = {k: orbit_reference(scene, frames[k], res, k, 1024 if quick else 4096) for k in ORBIT_CHECKED}
    path = mi.load_dict({"type": "path"})
    views.render_camera_path(scene, path, frames[:1], spp=1, seed=999)
    t0 = time.perf_counter()
    images = views.render_camera_path(scene, path, frames, spp=PATH_ORBIT_SPP, seed=1)
    path_seconds = time.perf_counter() - t0
    target = {k: np.array(errors(np.array(images[k])[..., :3], *refs[k])) for k in refs}
    say("\n### Orbit: %d frames at %d px, `%s` sampler (path %d spp a frame: %.1f s in all)\n"
        % (ORBIT_FRAMES, res, sampler, PATH_ORBIT_SPP, path_seconds))
    say("| method | settings | criterion | display spp | total s (solve + frames) | / path | worst frame RMSE / path's |")
    say("|---|---|---|---|---|---|---|")
    for method, configs in ORBIT_METHODS.items():
        for cfg in configs:
            views.render_camera_path(scene, mi.load_dict(cfg), frames[:1], spp=1, seed=998)     # compile
            found = {}
            for spp in kept_counts(sampler, ORBIT_SPP):
                integ = mi.load_dict(cfg)
                t0 = time.perf_counter()
                out = views.render_camera_path(scene, integ, frames, spp=spp, seed=2)
                seconds = time.perf_counter() - t0
                worst = np.max([np.array(errors(np.array(out[k])[..., :3], *refs[k])) / target[k] for k in refs], axis=0)
                for c, name in enumerate(("full image", "away from the light")):
                    if name not in found and (worst[c] <= 1.0 or spp == ORBIT_SPP[-1]):
                        found[name] = (spp, seconds, worst[c])
                if len(found) == 2:
                    break
            settings = ", ".join("%s %s" % (k, v) for k, v in cfg.items() if k != "type")
            for name, (spp, seconds, worst) in found.items():
                say("| %s | %s | %s | %d | %.2f | %.2f | %.2f |" % (method, settings, name, spp, seconds,
                                                                   seconds / path_seconds, worst))


def orbit_reference(scene, transform, res, k, spp):
    """(image, per-pixel noise variance, pixels away from the light) of frame ``k``."""
    path = os.path.join(CACHE, "solution_views_orbit_%dpx_%dspp_f%02d_of%d.npy" % (res, spp, k, ORBIT_FRAMES))
    if not os.path.exists(path):
        integ = mi.load_dict({"type": "path"})
        chunk = max(1, min(spp // 2, (1 << 22) // (res * res)))
        runs = [np.array(views.render_camera_path(scene, integ, [transform], spp=chunk, seed=5000 + c)[0],
                         dtype=np.float64)[..., :3] for c in range(max(2, spp // chunk))]
        halves = np.stack([np.mean(runs[0::2], axis=0), np.mean(runs[1::2], axis=0)])
        os.makedirs(CACHE, exist_ok=True)
        np.save(path, halves)
    halves = np.load(path)
    ref = halves.mean(axis=0)
    return ref, (halves[0] - halves[1]) ** 2 / 4.0, rsm.away_from_light(ref)


def first(say):
    d, _ = rsm.scene_dict("cornell", 128)
    say("\n### First image (Cornell box, 128 px; kernels compiled by an earlier render of the process)\n")
    say("| method | seconds to the first preview | previews |")
    say("|---|---|---|")
    for method, configs in METHODS.items():
        scene = mi.load_dict(d)
        warm = mi.load_dict(configs[0])
        mi.render(scene, integrator=warm, spp=1, seed=997)
        scene = mi.load_dict(d)
        integ = mi.load_dict(dict(configs[0], preview_every=1))
        stamps = []
        t0 = time.perf_counter()
        integ.preview_callback = lambda image, done, total: stamps.append(time.perf_counter() - t0)
        mi.render(scene, integrator=integ, spp=1, seed=3)
        say("| %s | %.2f | %d |" % (method, stamps[0] if stamps else float("nan"), len(stamps)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="one setting per method, short references")
    ap.add_argument("--parts", default="single,orbit,first")
    ap.add_argument("--orbit-samplers", default="independent,ldsampler",
                    help="the scene samplers the orbit is measured with (comma-separated Mitsuba sampler names)")
    ap.add_argument("--write-docs", action="store_true", help="rewrite the results part of docs/solutions.md")
    args = ap.parse_args()
    lines = []

    def say(text):
        print(text, flush=True)
        lines.append(text)
    parts = args.parts.split(",")
    if "single" in parts:
        for name, res in (("cornell", 128), ("cornell", 256), ("cornell_closed", 128)):
            if args.quick and res != 128:
                continue
            single(name, res, args.quick, say)
    if "orbit" in parts:
        for sampler in args.orbit_samplers.split(","):
            orbit(128, args.quick, say, sampler)
    if "first" in parts:
        first(say)
    if args.write_docs:
        text = open(DOCS).read()
        head = text[:text.index("<!-- results -->") + len("<!-- results -->")]
        with open(DOCS, "w") as f:
            f.write(head + "\n\n`python3 benchmarks/solution_views.py%s`:\n" % (" --quick" if args.quick else "")
                    + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
