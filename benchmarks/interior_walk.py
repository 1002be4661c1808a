"""Walkthroughs of the interiors: one solve and every view of a camera path through the
room, against Mitsuba's `path` rendering every view, timed end to end (docs/interiors.md).

Per scene (`interiors.py`; default room, corridor and skylight) at 128 x 96 px, the 60
views of ``interiors.camera_path`` (a walk at eye height):

1. **References**: every tenth view (frames 0, 10, ..., 50) rendered by `path` at
   ``--ref-spp`` (independent sampler) as two independent halves, whose difference
   removes the reference's own noise from every MSE; cached in benchmarks/.cache by the
   scene's dict, the views and the spp (the file named by ``interiors.scene_key``), and an
   emission-only render (``max_depth`` 1) of each, whose non-zero pixels and their 3 x 3
   neighbours are left out of the 'away from emitters' error.
2. **path**: ``max_depth`` -1 with ``--path-sampler`` (default `orthogonal`, the best of
   Mitsuba's samplers on these interiors) at ``--path-spp`` (rounded as the sampler
   rounds: 256 -> 289 for `orthogonal`) renders every view. Its RMSE on each checked view,
   on the full image and away from emitters, is the target.
3. **Solution methods**: `qmc_lighttrace` and `ray_bundle` at their defaults, each with
   ``display='smooth'`` and ``display='baked'``, with the scene's independent sampler. A
   ladder of camera spp 1, 2, 4, ... up to ``--max-spp``: every rung solves once (a new
   integrator) and displays all views (``views.render_camera_path``); the ladder stops at
   the first rung whose worst checked view reaches path's RMSE, per criterion, or once a
   rung takes longer than ``--cap`` times path's total. Where no rung reaches it, the
   rung of the lowest worst ratio is reported with that ratio.

Timing, as in `interior_bench.py`: every timed walk loads the scene anew from its dict and
runs from the loaded scene to the last image in numpy (integrator, patch table, field,
solve and displays inside; the setup cache off unless ``--setup-cache``); kernels are
warmed up on the first view on another scene object, and the compilation inside the
timed walk (Dr.Jit's kernel history, ``interior_ladder.compile_seconds``) is subtracted.
Target: a walkthrough at path's RMSE in at most 0.2 x path's total time. Run from the
repository root (``--quick``: a smoke run of a few minutes):

    python3 benchmarks/interior_walk.py [--quick] [--scenes room,corridor,skylight] [--write-docs]
"""
import argparse
import os
import sys
import time

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401  (registers the plugins)
from mi_plugins.app import cached_references  # noqa: E402
from mi_plugins.solution import views  # noqa: E402
from mi_plugins.solution.display import DISPLAYS  # noqa: E402

import interiors  # noqa: E402  (run as a script: its folder is on the path)
from interior_ladder import Fresh, compile_seconds, integrator_of, spp_of  # noqa: E402
from interior_report import errors  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DOCS = os.path.join(ROOT, "docs", "interiors.md")
CACHE = os.path.join(HERE, ".cache")
MARKERS = "<!-- walk:start -->", "<!-- walk:end -->"
#: the solution methods: each integrator at its defaults with each display it has of these
METHODS = {"%s %s" % (kind, disp): {"type": kind, "display": disp}
           for kind in ("qmc_lighttrace", "ray_bundle") for disp in ("smooth", "baked") if disp in DISPLAYS}
CRITERIA = ("full image", "away from emitters")
TARGET = 0.2          # the walkthrough's target: at most this fraction of path's total seconds
CHECK_EVERY = 10      # frames 0, 10, 20, ... are checked against references


def say_to(lines):
    def say(text=""):
        print(text, flush=True)
        lines.append(text)
    return say


def note(text):
    print("  " + text, file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------- references
def away_from_emitters(emission):
    """Pixels none of whose 3 x 3 neighbours sees an emitter (non-zero in ``emission``)."""
    seen = np.pad(emission.max(axis=-1) > 0, 1)
    windows = np.lib.stride_tricks.sliding_window_view(seen, (3, 3))
    return ~windows.any(axis=(-2, -1))


def references(name, width, walk, spp):
    """{frame: (reference, per-pixel variance of its noise, pixels away from emitters)} of
    the checked frames of ``walk``."""
    d = interiors.scene_dict(name, width)
    checked = list(range(0, len(walk), CHECK_EVERY))
    tag = "interior_walk_%s_%s" % (name, interiors.scene_key(name, width))
    refs = cached_references.path_references(d, spp, [walk[k] for k in checked], tag=tag, cache=CACHE, out=note)
    emission = views.render_camera_path(mi.load_dict(d), {"type": "path", "max_depth": 1},
                                        [walk[k] for k in checked], spp=64, seed=7)
    return {k: (r.image, r.variance, away_from_emitters(np.array(e, dtype=np.float64)))
            for k, r, e in zip(checked, refs, emission)}


def worst_ratios(images, refs, target):
    """The worst checked frame's RMSE / ``target``'s (full image, away from emitters)."""
    return np.max([np.array(errors(images[k], *refs[k])) / target[k] for k in refs], axis=0)


# ---------------------------------------------------------------------------- timed walks
def timed_walk(fresh, config, walk, spp, seed):
    """(images, seconds from the loaded scene to the last image in numpy less the
    compilation inside, compilation seconds) of a new ``config`` integrator over ``walk``."""
    fresh.load()
    dr.kernel_history()              # (clears it)
    t0 = time.perf_counter()
    integ = mi.load_dict(config)
    images = [np.array(image, dtype=np.float64)[..., :3]
              for image in views.render_camera_path(fresh.scene, integ, walk, spp=spp, seed=seed)]
    seconds = time.perf_counter() - t0
    compiled = compile_seconds()
    if getattr(integ, "solve_count", 1) != 1:
        raise RuntimeError("%s solved %d times on one walk" % (config["type"], integ.solve_count))
    if not all(np.all(np.isfinite(image)) for image in images):
        raise RuntimeError("%s: non-finite pixels at %d spp" % (config["type"], spp))
    return images, max(seconds - compiled, 1e-6), compiled


def warm_up(d, config, walk, spp):
    """Compiles the kernels: the first view on another scene object."""
    timed_walk(Fresh(d), config, walk[:1], spp, 999)


def run_path(name, args, walk, refs):
    method = "path_" + args.path_sampler
    d = interiors.scene_dict(name, args.width, sampler=args.path_sampler)
    spp = spp_of(method, args.path_spp)
    config = integrator_of(method, spp, args.width * ((3 * args.width) // 4))
    warm_up(d, config, walk, spp)
    images, seconds, compiled = timed_walk(Fresh(d), config, walk, spp, 1)
    note("path (%s): %d spp, %.2f s (+ %.2f s compiling)" % (args.path_sampler, spp, seconds, compiled))
    return dict(spp=spp, seconds=seconds, target={k: np.array(errors(images[k], *refs[k])) for k in refs})


def ladder_counts(args):
    """Camera spp 1, 2, 4, ... up to --max-spp that the display sampler keeps."""
    counts = [1 << k for k in range(int(args.max_spp).bit_length()) if 1 << k <= args.max_spp]
    return [n for n in counts if spp_of("path_" + args.display_sampler, n) == n]


def run_ladder(name, args, walk, refs, path, config):
    """[dict(spp, seconds, worst)] of the rungs, up to where every criterion reaches path."""
    d = interiors.scene_dict(name, args.width, sampler=args.display_sampler)
    warm_up(d, config, walk, 1)
    fresh, rungs = Fresh(d), []
    for i, spp in enumerate(ladder_counts(args)):
        images, seconds, compiled = timed_walk(fresh, config, walk, spp, 2 + i)
        rungs.append(dict(spp=spp, seconds=seconds, worst=worst_ratios(images, refs, path["target"])))
        note("%s: %d spp, %.2f s (+ %.2f s compiling), worst frame RMSE / path's %.2f, away %.2f"
             % (" ".join(config.values()), spp, seconds, compiled, *rungs[-1]["worst"]))
        if np.all(rungs[-1]["worst"] <= 1.0) or seconds > args.cap * path["seconds"]:
            break
    return rungs


def chosen(rungs, c):
    """(rung, reached) of criterion ``c``: the first rung at path's RMSE, else the closest."""
    reached = [r for r in rungs if r["worst"][c] <= 1.0]
    return (reached[0], True) if reached else (min(rungs, key=lambda r: r["worst"][c]), False)


# ---------------------------------------------------------------------------- report
def scene_table(name, args, say):
    walk = interiors.camera_path(name, args.frames)
    refs = references(name, args.width, walk, args.ref_spp)
    path = run_path(name, args, walk, refs)
    say("\n### %s: %d views at %d x %d px\n" % (name, len(walk), args.width, (3 * args.width) // 4))
    say("`path` (`%s` sampler, %d spp a view): **%.2f s** for the walk; checked views %s against `path` at %d spp "
        "(independent sampler); compilation excluded.\n"
        % (args.path_sampler, path["spp"], path["seconds"], ", ".join(map(str, refs)), args.ref_spp))
    say("| method | display | criterion | display spp | total s (solve + views) | / path | worst checked view "
        "RMSE / path's | <= %.1fx path |" % TARGET)
    say("|---|---|---|---:|---:|---:|---:|---|")
    for label in args.methods:
        config = METHODS[label]
        rungs = run_ladder(name, args, walk, refs, path, config)
        for c, criterion in enumerate(CRITERIA):
            rung, reached = chosen(rungs, c)
            ratio = rung["seconds"] / path["seconds"]
            say("| %s | %s | %s | %d%s | %.2f | %.2f | %.2f | %s |" % (
                config["type"], config["display"], criterion, rung["spp"], "" if reached else " (not reached)",
                rung["seconds"], ratio, rung["worst"][c], "yes" if reached and ratio <= TARGET else "no"))


def write_docs(lines, command):
    start, end = MARKERS
    text = open(DOCS).read()
    if start not in text or end not in text:
        raise SystemExit("%s has no %s ... %s markers" % (DOCS, start, end))
    body = "\nWritten by `%s` on %s (%d threads).\n%s\n" % (command, time.strftime("%Y-%m-%d"), dr.thread_count(),
                                                          "\n".join(lines))
    with open(DOCS, "w") as f:
        f.write(text.split(start)[0] + start + body + end + text.split(end, 1)[1])
    print("results written to %s" % os.path.relpath(DOCS, ROOT))


def arguments():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smoke run: 32 px, 12 views, references 256 spp, path 16 spp")
    p.add_argument("--scenes", default="room,corridor,skylight", help="comma-separated, of %s" % ", ".join(
        interiors.SCENES))
    p.add_argument("--width", type=int, default=None, help="image width, height 3/4 of it (default 128, quick 32)")
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated, of %s" % ", ".join(METHODS))
    p.add_argument("--frames", type=int, default=None, help="views of the walk (default 60, quick 12)")
    p.add_argument("--ref-spp", type=int, default=None, help="references' spp (default 2048, quick 256)")
    p.add_argument("--path-spp", type=int, default=None, help="path's spp a view (default 256, quick 16)")
    p.add_argument("--path-sampler", default="orthogonal", choices=interiors.SAMPLERS)
    p.add_argument("--display-sampler", default="independent", choices=interiors.SAMPLERS,
                   help="the scene's sampler for the solution methods' displays")
    p.add_argument("--max-spp", type=int, default=256, help="the ladder's largest display spp")
    p.add_argument("--cap", type=float, default=1.0, help="the ladder stops after a walk longer than this times "
                                                           "path's")
    p.add_argument("--setup-cache", action="store_true", help="keep the package's setup cache on (default off)")
    p.add_argument("--write-docs", action="store_true", help="write the tables into docs/interiors.md")
    args = p.parse_args()
    for key, full, quick in (("width", 128, 32), ("frames", 60, 12), ("ref_spp", 2048, 256), ("path_spp", 256, 16)):
        setattr(args, key, getattr(args, key) or (quick if args.quick else full))
    args.scenes = args.scenes.split(",")
    args.methods = args.methods.split(",")
    for name in args.methods:
        if name not in METHODS:
            p.error("unknown method %r; choose from %s" % (name, ", ".join(METHODS)))
    for name in args.scenes:
        if name not in interiors.SCENES:
            p.error("unknown scene %r; choose from %s" % (name, ", ".join(interiors.SCENES)))
    return args


def main():
    args = arguments()
    if not args.setup_cache:
        os.environ["MI_PLUGINS_SETUP_CACHE"] = "off"     # every walk pays its setup, as a first render does
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    t_start, lines = time.perf_counter(), []
    say = say_to(lines)
    print("%d threads; load average at start %.1f" % (dr.thread_count(), os.getloadavg()[0]), flush=True)
    for name in args.scenes:
        scene_table(name, args, say)
    print("\nload average at the end %.1f; total run time %.0f s" % (os.getloadavg()[0], time.perf_counter() - t_start))
    if args.write_docs:
        write_docs(lines, "python3 benchmarks/interior_walk.py " + " ".join(sys.argv[1:]))


if __name__ == "__main__":
    main()
