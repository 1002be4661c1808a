"""Every method on the interior scenes (`interiors.py`), timed end to end, against `path`
with the best of Mitsuba's samplers, measured in the same run (docs/interiors.md).

Methods: `path` (max_depth -1) with each of Mitsuba's samplers (independent, stratified,
multijitter, orthogonal, ldsampler); `qmc_lighttrace` and `ray_bundle`, each with its
gather and with ``display='smooth'``, at their defaults (the scene's independent sampler),
and the same four with the scene on the ``ldsampler`` (suffix ``_ld``), whose numbers the
displays and gathers then draw after the film position.
The budget is `mi.render`'s spp, doubled from 1 until a render takes the largest equal
time (the last budget predicted from the speed so far); several seeds per budget. Every
timed render loads the scene anew from its dict and runs from `mi.load_dict` returned to
the image in numpy: the package's setup (patch table, dark splits, the display's field,
the solve) is inside; only kernel compilation is warmed up, by one render at the smallest
budget on another scene object. One child process per scene and method. Reference: a long
`path` render (independent sampler), cached under the system temp dir with its parameters
in the name, with an emission-only render whose non-zero pixels (and their 3 x 3
neighbours) are left out of the 'away from emitters' error. Run from the repository root:

    python3 benchmarks/interior_bench.py [--quick] [--scenes room,corridor,skylight,room_1m]
        [--methods ...] [--seeds 3] [--resolution 128] [--times 4,10,30,60] [--write-docs]
"""
import argparse
import hashlib
import json
import os
import subprocess
import sys
import time

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import mi_plugins  # noqa: E402,F401  (registers the plugins)

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
import interior_geometry as ig  # noqa: E402
import interior_report as report  # noqa: E402
import interiors  # noqa: E402
from interior_ladder import METHODS, ladder, reference_file, render_reference  # noqa: E402

ROOT = os.path.dirname(HERE)
DOCS = os.path.join(ROOT, "docs", "interiors.md")
MARK = "@@interior-result "


# ---------------------------------------------------------------------------- the parent
def run_key(args, sname, method):
    """Everything a child's result depends on (for --resume): scene, settings, code."""
    code = hashlib.sha1()
    for folder in ("integrators", "mi_plugins"):
        for base, _, files in sorted(os.walk(os.path.join(ROOT, folder))):
            for f in sorted(files):
                if f.endswith(".py"):
                    code.update(open(os.path.join(base, f), "rb").read())
    parts = (interiors.scene_key(sname, args.resolution), method, args.seeds, args.times, args.cap, args.ref_spp,
             args.max_rungs, args.setup_cache, mi.__version__, code.hexdigest(),
             *(open(os.path.join(HERE, f), "rb").read() for f in ("interior_bench.py", "interior_ladder.py")))
    return hashlib.sha1(repr(parts).encode()).hexdigest()[:12]


def run_child(args, what, timeout):
    """``--worker what`` in a fresh process (its progress on stderr): its result dict or an error note."""
    # every timed render pays its setup, as a first render does: the setup cache is off
    # (``--setup-cache``: on, as a user who renders the same scene again)
    env = dict(os.environ, MI_PLUGINS_SETUP_CACHE=os.environ.get("MI_PLUGINS_SETUP_CACHE", "on")
               if args.setup_cache else "off")
    if env["MI_PLUGINS_SETUP_CACHE"] == "on":
        env.pop("MI_PLUGINS_SETUP_CACHE")
    proc = subprocess.run([sys.executable, os.path.abspath(__file__), *sys.argv[1:], "--worker", what],
                          stdout=subprocess.PIPE, text=True, cwd=ROOT, timeout=timeout, env=env)
    lines = [l.split(MARK, 1)[1] for l in proc.stdout.splitlines() if MARK in l]   # (after Mitsuba's colour codes)
    if proc.returncode != 0 or not lines:
        return None, "failed: child exited with code %s" % proc.returncode
    return json.loads(lines[-1]), None


def describe(args, sname, results):
    tris = next((r["triangles"] for r in results.values() if r.get("triangles")), interiors.triangles(sname))
    kept = next((r["kept"] for r in results.values() if r.get("kept")), float("nan"))
    return ("%d triangles, %d x %d px, reference `path` %d spp; away from emitters: %.0f %% of the pixels."
            % (tris, args.resolution, (3 * args.resolution) // 4, args.ref_spp, 100 * kept))


def write_docs(lines, command):
    start, end = "<!-- results:start -->", "<!-- results:end -->"
    text = open(DOCS).read()
    if start not in text or end not in text:
        raise SystemExit("%s has no %s ... %s markers" % (DOCS, start, end))
    body = "\nWritten by `%s` on %s (%d threads).\n\n%s\n" % (command, time.strftime("%Y-%m-%d"), dr.thread_count(),
                                                             "\n".join(lines).strip("\n"))
    open(DOCS, "w").write(text.split(start)[0] + start + body + end + text.split(end, 1)[1])
    print("results written to %s" % os.path.relpath(DOCS, ROOT))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smoke run (a few minutes): room, 32 px, 2 seeds, "
                   "times 2,4, reference 256 spp, path (independent) and qmc_lighttrace")
    p.add_argument("--scenes", default=None, help="comma-separated (default all: %s)" % ",".join(interiors.SCENES))
    p.add_argument("--methods", default=None, help="comma-separated (default all: %s)" % ",".join(METHODS))
    p.add_argument("--seeds", type=int, default=None, help="renders per budget (default 3, quick 2)")
    p.add_argument("--resolution", type=int, default=None, help="image width, height 3/4 of it (default 128)")
    p.add_argument("--times", default=None, help="equal times, seconds (default 4,10,30,60; quick 2,4)")
    p.add_argument("--ref-spp", type=int, default=None, help="reference spp (default 16384, quick 256)")
    p.add_argument("--cap", type=float, default=None, help="no render predicted above this (default 3 x the "
                                                            "largest time)")
    p.add_argument("--max-rungs", type=int, default=16, help="most budgets per method")
    p.add_argument("--resume", action="store_true", help="reuse the results of an earlier run with the same "
                                                         "settings, scene and code (kept in the temp dir)")
    p.add_argument("--write-docs", action="store_true", help="write the tables into docs/interiors.md")
    p.add_argument("--setup-cache", action="store_true", help="keep the package's setup cache on (default off: "
                                                               "every render pays its setup)")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    for key, full, quick in (("seeds", 3, 2), ("resolution", 128, 32), ("times", "4,10,30,60", "2,4"),
                             ("ref_spp", 16384, 256), ("scenes", ",".join(interiors.SCENES), "room"),
                             ("methods", ",".join(METHODS), "path_independent,qmc_gather,qmc_smooth")):
        setattr(args, key, getattr(args, key) or (quick if args.quick else full))
    args.times = tuple(float(t) for t in str(args.times).split(","))
    args.cap = args.cap or 3.0 * max(args.times)
    scenes, methods = args.scenes.split(","), args.methods.split(",")
    for name, valid in [(s, interiors.SCENES) for s in scenes] + [(m, METHODS) for m in methods]:
        if name not in valid:
            p.error("unknown name %r; choose from %s" % (name, ", ".join(valid)))
    if args.worker:
        sname, what = args.worker.split(":")
        return print(MARK + json.dumps(render_reference(args, sname) if what == "reference"
                                       else ladder(args, sname, what)))
    t_start, lines, per_scene = time.perf_counter(), [], {}
    say = lambda s: (print(s), lines.append(s))
    print("%d px, %d seeds, times %s s, %d threads; load average at start %s" % (
        args.resolution, args.seeds, args.times, dr.thread_count(), os.getloadavg()), flush=True)
    for sname in scenes:
        if not os.path.exists(reference_file(args, sname)):
            info, note = run_child(args, sname + ":reference", None)
            if note:
                raise SystemExit("reference of %s: %s" % (sname, note))
            print("reference %s: %d spp in %.0f s" % (sname, info["spp"], info["seconds"]), flush=True)
        results = {}
        for method in methods:
            store = os.path.join(ig.cache_dir(), "result-%s-%s-%s.json" % (sname, method, run_key(args, sname, method)))
            if args.resume and os.path.exists(store):
                results[method] = json.load(open(store))
                print("  [%s / %s: reused %s]" % (sname, method, os.path.basename(store)), flush=True)
                continue
            t0 = time.perf_counter()
            res, note = run_child(args, "%s:%s" % (sname, method), 4 * 3600)
            results[method] = res or dict(rungs=[], status=note)
            if res:
                json.dump(res, open(store, "w"))
            print("  [%s / %s: %.0f s, load average %.1f]" % (sname, method, time.perf_counter() - t0,
                                                               os.getloadavg()[0]), flush=True)
        table, per_scene[sname] = report.scene_tables(sname, describe(args, sname, results), results, args.times)
        for line in table:
            say(line)
    per_scene = {k: v for k, v in per_scene.items() if v}
    if per_scene:
        say("### The family's medians\n\nMedian over the scenes (%s) of each method's median RMSE ratio to the "
            "scene's best `path` at equal time: full image / away from emitters (compilation excluded) / full "
            "image by the wall clock (number of scenes with an image by then):\n" % ", ".join(per_scene))
        for line in report.family_lines(per_scene, args.times):
            say(line)
    say("\nLoad average at the end: %.1f, %.1f, %.1f; total run time %.0f s." % (*os.getloadavg(),
                                                                             time.perf_counter() - t_start))
    if args.write_docs:
        write_docs(lines, "python3 benchmarks/interior_bench.py " + " ".join(sys.argv[1:]))


if __name__ == "__main__":
    main()
