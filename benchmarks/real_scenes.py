"""Error, time and memory of the integrators on real scenes: the Cornell box, alone and
with a 70 000 or a 1 000 000 triangle mesh standing in it (real_scene_meshes.py).

Every integrator (`path`, `ptracer`, `stochastic_ray`, `ray_bundle` with its defaults
and with the paper's settings, `qmc_lighttrace`) renders every scene at doubling budgets, each twice, in a
fresh child process after a tiny warm-up render; against a cached long `path` reference:
seconds, RMSE (also away from the visible light), bias, noise, mean relative to the
reference, RMSE ratio to `path` at equal time, seconds per `ray_bundle` iteration, peak
memory, scaling with the triangle count, and a log-log plot. Columns, formulas and the
scenes: docs/real_scenes.md. Run from the repository root:

    python3 benchmarks/real_scenes.py [--quick] [--scenes cornell,cornell_70k,cornell_1m]
        [--integrators path,...] [--resolution 128] [--ref-spp 16384] [--cap 120] [--write-docs]
"""
import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401  (registers the plugins)
from mi_plugins.integrators.ray_bundle.integrator import PAPER_SETTINGS  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:   # the helper modules next to this file
    sys.path.insert(0, HERE)
import real_scene_meshes as rsm  # noqa: E402
from analysis import interp_loglog  # noqa: E402

ROOT = os.path.dirname(HERE)
DOCS = os.path.join(ROOT, "docs", "real_scenes.md")
MARK = "@@worker-result "
INTEGRATORS = ("path", "ptracer", "stochastic_ray", "ray_bundle", "ray_bundle_paper", "qmc_lighttrace",
               "ray_bundle_smooth", "qmc_smooth")
PAPER = {k: v for k, v in PAPER_SETTINGS.items() if k != "iterations"}   # the budget sets the iterations
SETTINGS = {"path": "max_depth -1", "ptracer": "max_depth -1", "stochastic_ray": "defaults: 32 it, burn 8",
            "ray_bundle": "defaults: 64 ch, res 32", "ray_bundle_paper": "paper: 1 ch, res 128",
            "qmc_lighttrace": "defaults (1e5 paths)", "ray_bundle_smooth": "smooth, 8 spp per it",
            "qmc_smooth": "smooth, 25k paths, 8 spp"}
UNIT = {"ray_bundle": "it", "ray_bundle_paper": "it", "ray_bundle_smooth": "it", "qmc_smooth": "x 25k"}   # others: spp
#: the view-independent displays: one solve and a display of it, both grown with the budget
#: (by default 8 camera samples per iteration or per 25 000 particle paths: a camera sample of the
#: display costs a small fraction of either; away from the light the solution's noise weighs most,
#: measured best at 8 on the Cornell boxes at 128 px, 0.5x `path` on the full image kept)
DISPLAY_SPP = [8]   # camera samples per budget unit (--display-spp)
SMOOTH = {"ray_bundle_smooth": lambda b: (dict(type="ray_bundle", display="smooth", iterations=b),
                                          DISPLAY_SPP[0] * b),
          "qmc_smooth": lambda b: (dict(type="qmc_lighttrace", display="smooth", samples=25000 * b),
                                   DISPLAY_SPP[0] * b)}
STEPPED = ("stochastic_ray", "ray_bundle", "ray_bundle_paper", "ray_bundle_smooth")   # iterations, a progress callback
SCALING = ("ray_bundle", "ray_bundle_paper", "qmc_lighttrace")   # the columns of the scaling table


# ---------------------------------------------------------------------------- one child process
def config(name, budget):
    """(integrator dict, spp) of a budget: spp for path, ptracer and stochastic_ray; global
    iterations for ray_bundle (iterations = budget, spp 1; burn-in 8); spp for qmc_lighttrace with its default particle paths (100 000: a fixed
    cost, and a fixed error of the patch radiances that more camera samples do not lower)."""
    if name in SMOOTH:
        return SMOOTH[name](budget)
    if name in ("path", "ptracer"):
        return dict(type=name, max_depth=-1), budget
    if name == "stochastic_ray":
        return dict(type=name), budget
    if name.startswith("ray_bundle"):
        d = dict(type="ray_bundle", **(PAPER if name == "ray_bundle_paper" else {}))
        return dict(d, iterations=budget), 1
    return dict(type=name), budget


rss_mb = lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # own peak (Linux: KiB)


def render(scene, integrator, spp, seed, limit):
    """Timed render -> (image, seconds without compile, compile seconds, stop): the package's
    iterative integrators wait for each step's kernels (dr.sync_thread) and stop once the
    render has run `limit` seconds; stop = (steps done, steps planned, seconds) or None.
    Dr.Jit's kernel history (compile times) is read and cleared after every step: kept for
    a whole render of thousands of iterations it alone grew to 3.5 GB."""
    stop, comp, t0 = [], [0.0], time.perf_counter()
    compiled = lambda: sum(k.get("backend_time", 0.0) for k in dr.kernel_history() if k.get("cache_hit", 1) == 0) / 1e3
    if hasattr(integrator, "progress_callback"):
        def guard(done, total):
            dr.sync_thread()
            comp[0] += compiled()
            if time.perf_counter() - t0 > limit:
                stop.append((done, total, time.perf_counter() - t0))
                return False
        integrator.progress_callback = guard
    dr.kernel_history()   # clears it
    image = np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed), dtype=np.float64)
    wall = time.perf_counter() - t0
    comp[0] += compiled()
    return image, max(wall - comp[0], 1e-6), comp[0], (stop[0] if stop else None)


def rung_stats(a, b, ref, ref_var, keep):
    """RMSE^2 = mean of both renders' MSE - the reference's noise^2 (the correction capped at
    halving the RMSE); noise^2 = var = mean((a - b)^2) / 2; bias^2 = max(MSE(mean of a, b)
    - var / 2 - ref noise^2, 0); the same RMSE over the pixels `keep` (away from the
    visible light); image mean / the reference's."""
    mse = lambda x, m=Ellipsis: float(np.mean(((x - ref) ** 2)[m]))
    var = float(np.mean((a - b) ** 2)) / 2.0
    raw = lambda m: 0.5 * (mse(a, m) + mse(b, m))
    rmse = lambda m: math.sqrt(max(raw(m) - float(np.mean(ref_var[m])), 0.25 * raw(m), 1e-24))
    return dict(rmse=rmse(Ellipsis), rmse_x=rmse(keep), noise=math.sqrt(var),
                bias=math.sqrt(max(mse(0.5 * (a + b)) - var / 2.0 - float(np.mean(ref_var)), 0.0)),
                mean_rel=float(0.5 * (a.mean() + b.mean()) / ref.mean()))


def ladder(args, sname, name):
    """One integrator's warm-up and ladder on one scene (run in a child process)."""
    ref, ref_var = rsm.reference(sname, args.resolution, args.ref_spp, render=False)
    keep = rsm.away_from_light(ref)
    d, triangles = rsm.scene_dict(sname, args.resolution)
    scene = mi.load_dict(d)
    out = dict(triangles=triangles, base_mb=rss_mb(), rungs=[], status=None, kept=float(keep.mean()))
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    # the tiny warm-up (1 spp): 2 iterations (1 burn-in), or 1000 particle paths
    tiny = dict(samples=1000) if name in ("qmc_lighttrace", "qmc_smooth") else dict(iterations=2, burn_in=1) if name in STEPPED else {}
    warm = mi.load_dict(dict(config(name, 1)[0], **tiny))
    _, out["warmup_s"], _, stop = render(scene, warm, 1, seed=999, limit=args.cap)
    out["patches"] = len(warm.triangle_areas) if name == "qmc_lighttrace" else None
    took = lambda st: "> %.3g s (%d of %d steps in %.1f s: about %.3g s for all)" % (
        args.cap, *st, st[2] * st[1] / st[0])
    if stop:
        out["status"], out["step_s"] = "not run: the 2-iteration warm-up took " + took(stop), stop[2] / stop[0]
    # ray_bundle's gather from 12 iterations (its burn-in's 8 and 4 averaged): on the rooms
    # at 128 px its ladder then brackets t* instead of starting past it
    budget, spent = (12 if name == "ray_bundle" else 16 if name.startswith("ray_bundle") else 1), 0.0
    # path, the reference of every ratio, goes on past --max-rungs until a budget takes t*:
    # its error at t* is then measured, not extrapolated (path's curve is steeper than
    # slope -1/2 at small budgets, so an extrapolation flattered the others by about 10 %)
    short = lambda: name == "path" and args.t_star > 0 and out["rungs"][-1]["seconds"] < args.t_star
    while not out["status"] and (len(out["rungs"]) < args.max_rungs or short()):
        if out["rungs"] and spent + 4 * out["rungs"][-1]["seconds"] > args.cap:
            break   # the next budget (twice the work, two renders) would pass the cap
        cfg, spp = config(name, budget)
        renders = []
        for r in range(2):
            image, sec, comp, stop = render(scene, mi.load_dict(cfg), spp, (len(out["rungs"]) + 1) * 1000 + r, args.cap)
            spent += sec
            if stop or (not out["rungs"] and sec > args.cap):
                out["status"] = ("ladder stopped at budget %d: one pass took " % budget if out["rungs"] else
                                 "not run: one pass took ") + (took(stop) if stop else "%.1f s" % sec)
                out["step_s"] = stop[2] / stop[0] if stop else None
                break
            renders.append((image, sec, comp))
        if len(renders) < 2:
            break
        out["rungs"].append(dict(budget=budget, seconds=0.5 * (renders[0][1] + renders[1][1]),
                                 compile=renders[0][2] + renders[1][2],
                                 **rung_stats(renders[0][0], renders[1][0], ref, ref_var, keep)))
        budget *= 2
    out["peak_mb"] = rss_mb()
    return out


# ---------------------------------------------------------------------------- parent process
def run_child(args, what):
    """Run `--worker what` in a fresh process (stdout to a temporary file, stderr shown);
    stop it when its resident memory passes --max-mb. Returns (result dict or None, note)."""
    with tempfile.TemporaryFile("w+") as out:
        proc = subprocess.Popen([sys.executable, os.path.abspath(__file__), *sys.argv[1:], "--worker", what],
                                stdout=out, cwd=ROOT)
        killed = None
        while proc.poll() is None:   # VmRSS in KiB; the file is gone once the child has exited
            with open("/proc/%d/status" % proc.pid) as f:
                rss = max([int(l.split()[1]) / 1024.0 for l in f if l.startswith("VmRSS:")] + [0.0])
            if rss > args.max_mb and killed is None:
                killed = "stopped: resident memory passed --max-mb %.0f MB" % args.max_mb
                proc.kill()
            time.sleep(0.2)
        out.seek(0)
        lines = [l for l in out.read().splitlines() if l.startswith(MARK)]
    if killed or proc.returncode != 0 or not lines:
        return None, killed or "failed: child exited with code %s" % proc.returncode
    return json.loads(lines[-1][len(MARK):]), None


def per_iteration(name, res):
    """Seconds per global iteration of ray_bundle: difference of the two largest budgets
    ('~': of the only budget and the 2-iteration warm-up, or a stopped pass's average);
    seconds per pass of qmc_lighttrace at budget 1 (its defaults)."""
    r = res.get("rungs") or []
    if name.startswith("ray_bundle"):
        if len(r) >= 2:
            return "%.3g" % ((r[-1]["seconds"] - r[-2]["seconds"]) / (r[-1]["budget"] - r[-2]["budget"]))
        if r:
            return "~%.3g" % ((r[0]["seconds"] - res["warmup_s"]) / (r[0]["budget"] - 2))
        return "~%.3g" % res["step_s"] if res.get("step_s") else "-"
    return "%.3g/pass" % r[0]["seconds"] if name == "qmc_lighttrace" and r else "-"


def report(sname, results, args, say):
    """One scene's table: a row per budget; per integrator the ratios at t*, s/iter, peak MB."""
    tris, kept = (next((r[k] for r in results.values() if r.get(k)), 0) for k in ("triangles", "kept"))
    path = results.get("path", {}).get("rungs")
    t_star = args.t_star if args.t_star > 0 else path[len(path) // 2]["seconds"] if path else None
    ref_file = os.path.relpath(rsm.reference_path(sname, args.resolution, args.ref_spp), ROOT)
    say("\n%s: %d triangles, %d x %d px, reference path %d spp (%s); equal time t* = %s; 'excl.': the %.0f %% "
        "of pixels away from the visible light" % (sname, tris, args.resolution, args.resolution, args.ref_spp,
        ref_file, "%.3g s" % t_star if t_star else "- (no path ladder)", 100 * kept))
    say("%-16s %-22s %9s %9s %8s %8s %8s %8s %8s %7s %7s %10s %14s" % (
        "integrator", "settings", "budget", "seconds", "RMSE", "excl.", "bias", "noise", "mean rel",
        "/path", "excl.", "s/iter", "peak (base) MB"))
    at = lambda curve, key: interp_loglog([dict(seconds=p["seconds"], rmse=p[key]) for p in curve], t_star)
    ratio = lambda r, base, key: "%.3f%s" % (at(r, key)[0] / at(base, key)[0], "*" if at(r, key)[1] else "")
    for name, res in results.items():
        r = res.get("rungs")
        if not r:
            extra = "; s/iter %s, peak (base) %.0f (%.0f) MB" % (per_iteration(name, res), res["peak_mb"],
                                                                 res["base_mb"]) if res.get("peak_mb") else ""
            say("%-16s %-22s %s%s" % (name, SETTINGS[name], res.get("status") or "failed", extra))
            continue
        for k, p in enumerate(r):
            head = (name, SETTINGS[name]) if k == 0 else ("", "")
            tail = ((ratio(r, path, "rmse"), ratio(r, path, "rmse_x")) if t_star else ("-", "-")) + (
                per_iteration(name, res), "%.0f (%.0f)" % (res["peak_mb"], res["base_mb"]))
            say("%-16s %-22s %9s %9.4g %8.5f %8.5f %8.5f %8.5f %8.4f %7s %7s %10s %14s" % (
                *head, "%d %s" % (p["budget"], UNIT.get(name, "spp")), p["seconds"], p["rmse"], p["rmse_x"],
                p["bias"], p["noise"], p["mean_rel"], *(tail if k == 0 else ("",) * 4)))
        if res["status"]:
            say("%-16s %-22s %s" % ("", "", res["status"]))
    pt, sr = results.get("ptracer", {}).get("rungs"), results.get("stochastic_ray", {}).get("rungs")
    if t_star and pt and sr:
        say("stochastic_ray / ptracer at t*: %s, excl. %s" % (ratio(sr, pt, "rmse"), ratio(sr, pt, "rmse_x")))
    say("(* extrapolated with slope -1/2 beyond the curve; compile time subtracted from timed renders: %.2f s)"
        % sum(p["compile"] for res in results.values() for p in res.get("rungs") or []))


def plot(all_results, args):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(all_results), figsize=(5.2 * len(all_results), 4.2), squeeze=False)
    for ax, (sname, results) in zip(axes[0], all_results.items()):
        for name, res in results.items():
            r, c = res.get("rungs"), "C%d" % INTEGRATORS.index(name)
            if not r:
                ax.plot([], [], color=c, label="%s (not run)" % name)
                continue
            ax.loglog([p["seconds"] for p in r], [p["rmse"] for p in r], "-o", ms=3, color=c, label=name)
            ax.loglog([p["seconds"] for p in r], [p["rmse_x"] for p in r], "--.", lw=0.8, ms=3, color=c)
        ax.set(xlabel="seconds per render (compile excluded)", title=sname,
               ylabel="RMSE vs reference (dashed: away from the light)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("Real scenes: error versus time, %d x %d px" % (args.resolution, args.resolution))
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(args.plot)), exist_ok=True)
    fig.savefig(args.plot, dpi=110)
    print("plot: %s" % os.path.relpath(args.plot, ROOT))


def write_docs(lines, command):
    """Replace the part of docs/real_scenes.md between the two result markers."""
    start, end = "<!-- results:start -->", "<!-- results:end -->"
    text = open(DOCS).read()
    if start not in text or end not in text:
        raise SystemExit("%s has no %s ... %s markers" % (DOCS, start, end))
    body = "\nWritten by `%s` on %s (%d threads).\n\n```text\n%s\n```\n" % (
        command, time.strftime("%Y-%m-%d"), dr.thread_count(), "\n".join(lines).strip("\n"))
    open(DOCS, "w").write(text.split(start)[0] + start + body + end + text.split(end, 1)[1])
    print("results written to %s" % os.path.relpath(DOCS, ROOT))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="32 px, reference 1024 spp, cap 5 s, cornell and cornell_70k")
    p.add_argument("--scenes", default=None, help="comma-separated subset of %s" % ", ".join(rsm.SCENES))
    p.add_argument("--integrators", default=",".join(INTEGRATORS))
    p.add_argument("--resolution", type=int, default=None, help="image side in pixels (default 128, quick 32)")
    p.add_argument("--ref-spp", type=int, default=None, help="reference spp (default 16384, quick 1024)")
    p.add_argument("--cap", type=float, default=None, help="seconds per configuration (default 120, quick 5)")
    p.add_argument("--max-rungs", type=int, default=None, help="most budgets per ladder (default 12, quick 4)")
    p.add_argument("--max-mb", type=float, default=None,
                   help="stop a child above this resident memory (default half of MemAvailable at start)")
    p.add_argument("--scale", type=float, default=rsm.SCALE,
                   help="scene units per millimetre of the Cornell data (default 0.001: metres)")
    p.add_argument("--t-star", type=float, default=1.0,
                   help="equal time of the ratio columns, seconds (default 1; 0: path's middle budget)")
    p.add_argument("--plot", default=None, help="default docs/real_scenes.png (quick: benchmarks/.cache/)")
    p.add_argument("--write-docs", action="store_true", help="write the tables into docs/real_scenes.md")
    p.add_argument("--display-spp", type=int, default=8,
                   help="camera samples of the smooth displays per iteration or per 25 000 particle paths")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    DISPLAY_SPP[0] = args.display_spp
    for name in SMOOTH:
        SETTINGS[name] = SETTINGS[name].replace("8 spp", "%d spp" % args.display_spp)
    rsm.SCALE = args.scale
    args.plot = args.plot or os.path.join(ROOT, "benchmarks/.cache/real_scenes_quick.png" if args.quick
                                          else "docs/real_scenes.png")
    for key, full, quick in (("resolution", 128, 32), ("ref_spp", 16384, 1024), ("cap", 120.0, 5.0),
                             ("max_rungs", 12, 4)):
        setattr(args, key, getattr(args, key) or (quick if args.quick else full))
    scenes = (args.scenes or ("cornell,cornell_70k" if args.quick else ",".join(rsm.SCENES))).split(",")
    names = [s for s in args.integrators.split(",") if s]
    for s, valid in [(s, rsm.SCENES) for s in scenes] + [(s, INTEGRATORS) for s in names]:
        if s not in valid:
            p.error("unknown name %r; choose from %s" % (s, ", ".join(valid)))
    if args.max_mb is None:
        with open("/proc/meminfo") as f:
            args.max_mb = 0.5 * next(int(l.split()[1]) for l in f if l.startswith("MemAvailable:")) / 1024.0
    if args.worker:
        sname, what = args.worker.split(":")
        ref = what == "reference" and rsm.reference(sname, args.resolution, args.ref_spp)
        return print(MARK + json.dumps({} if ref else ladder(args, sname, what)))
    t_start = time.perf_counter()
    print("%d x %d px, llvm_ad_rgb, %d threads; cap %.0f s per configuration, at most %d budgets, children "
          "stopped above %.0f MB" % (args.resolution, args.resolution, dr.thread_count(), args.cap,
                                     args.max_rungs, args.max_mb), flush=True)
    all_results, lines = {}, []
    say = lambda s: (print(s.rstrip()), lines.append(s.rstrip()))
    for sname in scenes:
        _, note = run_child(args, sname + ":reference")
        if note:
            raise SystemExit("reference of %s: %s" % (sname, note))
        results = {}
        for name in names:
            t0 = time.perf_counter()
            results[name], note = run_child(args, "%s:%s" % (sname, name))
            results[name] = results[name] or dict(rungs=[], status=note)
            print("  [%s / %s: %.1f s]" % (sname, name, time.perf_counter() - t0), flush=True)
        all_results[sname] = results
        report(sname, results, args, say)
    say("\nScaling with triangle count: ray_bundle s per global iteration, qmc_lighttrace s per pass (budget 1)")
    say("%-12s %10s %9s" % ("scene", "triangles", "patches") + "".join(" %18s" % n for n in names if n in SCALING))
    for sname, results in all_results.items():
        get = lambda key: next((r[key] for r in results.values() if r.get(key)), 0)
        say("%-12s %10d %9s" % (sname, get("triangles"), get("patches") or "-")
            + "".join(" %18s" % per_iteration(n, results[n]) for n in names if n in SCALING))
    plot(all_results, args)
    if args.write_docs:
        write_docs(lines, "python3 benchmarks/real_scenes.py " + " ".join(sys.argv[1:]))
    print("total run time %.1f s" % (time.perf_counter() - t_start))


if __name__ == "__main__":
    main()
