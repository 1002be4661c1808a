"""Error versus wall time of `ray_bundle`, `stochastic_ray`, Mitsuba `path` and `ptracer`.

`ray_bundle` runs three times: as the paper's algorithm (``ray_bundle``), with
``first_shot=true`` (``ray_bundle_fs``: direct light by a light sample with MIS, the
bundles carrying only reflected radiance), and with ``first_shot=true,
average_diffuse=true`` (``ray_bundle_avg``: final gathering from the diffuse patches'
averages over chains and iterations), same resolution, chains and estimate.

The stochastic-iteration benchmark: in one run, every integrator renders every scene at a ladder of
budgets (doubling until a render takes --seconds), and the RMSE of each image against
the exact image (analytic scenes) or a long `path` reference (the room) is recorded
against the wall time of the render. Every budget is rendered --repeats times (default
2, different seeds) and its RMSE is the root mean square over them: one image's RMSE is
a noisy statistic, above all for `ray_bundle`, whose pixels all gather from the same
chains (an error shared by the whole image). Scenes (all closed, all triangle meshes):
the furnace sphere mesh, the analytic-scenes paper's three Sierpinski scenes of figure 4
and a closed Cornell-like room (reference: a long `path` render, 131072 spp, cached in
benchmarks/.cache/); see scenes.py.

Printed per scene: RMSE at the largest budget, mean image value against the exact
mean, log-log slope (-0.5 for an unbiased Monte Carlo method), RMSE ratio to `path`
at equal time (< 1: better than `path`), and rays traced per second relative to
`path`. Ray counts come from an untimed counting render per integrator and scene
(instrumented Python integrators, Python replicas of the C++ `path` and `ptracer`
loops; see ray_counting.py). Rays per second: the better of a curve's two largest renders.
Timing: time.perf_counter around `mi.render` + conversion to numpy, after one
warm-up render per integrator; the LLVM compile time of kernels that miss Dr.Jit's
cache during a timed render (read from Dr.Jit's kernel history) is subtracted and
reported ("compile"). Every integrator's ladder (with its warm-up and ray count) runs in
a fresh process of its own: in one process, a Dr.Jit integrator renders 20-25 % slower
after Mitsuba's C++ `path` has rendered there (measured on the room: 1.15 s -> 1.40 s
per render, persistent; up to 2.5x after several C++ integrators), which would charge
the order of the ladders to the Python integrators. ``--no-isolate`` runs everything in
one process with the ladders interleaved (rung k of every integrator, then rung k + 1).
Writes a log-log plot (one panel per scene, plus the paper's figure 4 as RMSE of
`ray_bundle` versus iterations on the three Sierpinski scenes).

This file is the driver (options, methods, timing, process isolation, main); next to it:
scenes.py (the scenes and the room's reference), ray_counting.py (rays traced per
render) and analysis.py (equal-time interpolation, slopes, report, plot). Run it from the
repository root:

    python3 benchmarks/stochastic_iteration.py [--quick] [--seconds 2.5] [--resolution 32]
        [--scenes furnace,sierpinski_diffuse_exact,...] [--out benchmarks/stochastic_iteration.png]
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time
import warnings

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401  (registers the plugins)

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:   # the helper modules next to this file (python3 puts it first only for a script)
    sys.path.insert(0, HERE)
from analysis import monotone_warnings, plot, report_scene, summary  # noqa: E402
from ray_counting import count_rays  # noqa: E402
from scenes import SCENES, make_scenes  # noqa: E402

WORKER_MARK = "@@worker-result "
INTEGRATORS = ("path", "ptracer", "stochastic_ray", "ray_bundle", "ray_bundle_fs", "ray_bundle_avg")


# ---------------------------------------------------------------------------- integrators
class Method:
    """An integrator with a budget ladder: ``config(b)`` -> (integrator dict, spp)."""

    def __init__(self, name, ladder, config, budget_label):
        self.name, self.ladder, self.config, self.budget_label = name, ladder, config, budget_label


def methods(args):
    doubling = [2 ** k for k in range(20)]
    sr = dict(type="stochastic_ray", iterations=args.sr_iterations, burn_in=args.burn_in, max_depth=-1)
    rb_ladder = [args.burn_in + 8 * 2 ** k for k in range(16)]
    # the paper's algorithm unless `extra` says otherwise (the defaults are the tuned settings)
    rb = lambda n, **extra: (dict(dict(type="ray_bundle", iterations=n, burn_in=args.burn_in,
                                       resolution=args.bundle_resolution, chains=args.bundle_chains,
                                       estimate=args.bundle_estimate, first_shot=False, average_diffuse=False),
                                  **extra), 1)
    return {
        "path": Method("path", doubling, lambda b: (dict(type="path", max_depth=-1), b), "spp"),
        "ptracer": Method("ptracer", doubling, lambda b: (dict(type="ptracer", max_depth=-1), b), "spp"),
        "stochastic_ray": Method("stochastic_ray", doubling, lambda b: (dict(sr), b), "spp"),
        "ray_bundle": Method("ray_bundle", rb_ladder, rb, "iterations"),
        "ray_bundle_fs": Method("ray_bundle_fs", rb_ladder, lambda n: rb(n, first_shot=True), "iterations"),
        "ray_bundle_avg": Method("ray_bundle_avg", rb_ladder,
                                 lambda n: rb(n, first_shot=True, average_diffuse=True, gather_nee=args.gather_nee),
                                 "iterations"),
    }


# ---------------------------------------------------------------------------- timing
def compile_seconds():
    """LLVM compile time of the kernels that missed the cache since the last call."""
    return sum(k.get("backend_time", 0.0) for k in dr.kernel_history()
               if k.get("cache_hit", 1) == 0) / 1000.0


def timed_render(scene, spp, seed):
    dr.kernel_history()   # clears the history
    t0 = time.perf_counter()
    image = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
    wall = time.perf_counter() - t0
    comp = compile_seconds()
    return image, max(wall - comp, 1e-6), comp


def rmse(image, case):
    err2 = float(np.mean((image - case.expected()) ** 2))
    noise = getattr(case, "reference_noise", 0.0)
    # the reference's own noise adds in quadrature (independent): remove it (the
    # correction is capped at halving the raw RMSE)
    return math.sqrt(max(err2 - noise ** 2, 0.25 * err2))


def run_scene(case, meths, seconds, max_points, min_points, repeats):
    """Every integrator renders at its doubling ladder until one of its renders takes
    `seconds` (and at least `min_points` budgets); every budget is rendered `repeats`
    times with different seeds (RMSE: root mean square over them; seconds: mean). The
    ladders are interleaved (rung k of every integrator, then rung k+1) so that load
    from other processes affects all integrators alike. Returns
    {integrator: [dict(budget, seconds, compile, rmse, mean), ...]}."""
    scenes, curves = {}, {}
    for name, m in meths.items():   # warm-up: kernel compilation
        cfg, spp = m.config(m.ladder[0])
        scenes[name] = (cfg, case.scene(cfg))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mi.render(scenes[name][1], spp=spp, seed=999)
        curves[name] = []
    dr.kernel_history()
    active = list(meths)
    for k in range(max_points):
        for name in list(active):
            m = meths[name]
            cfg, spp = m.config(m.ladder[k])
            if cfg != scenes[name][0]:
                scenes[name] = (cfg, case.scene(cfg))
            renders = [timed_render(scenes[name][1], spp, seed=(k + 1) * 1000 + r) for r in range(repeats)]
            sec = float(np.mean([r[1] for r in renders]))
            curves[name].append(dict(budget=m.ladder[k], seconds=sec, compile=sum(r[2] for r in renders),
                                     rmse=math.sqrt(np.mean([rmse(r[0], case) ** 2 for r in renders])),
                                     mean=float(np.mean([r[0].mean() for r in renders]))))
            if sec >= seconds and k + 1 >= min_points:
                active.remove(name)
        if not active:
            break
    return curves


# ---------------------------------------------------------------------------- main
def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="short budgets (about a minute)")
    p.add_argument("--seconds", type=float, default=None,
                   help="stop a ladder once a render takes this long (default 2.5, quick 0.3)")
    p.add_argument("--resolution", type=int, default=32)
    p.add_argument("--scenes", default=",".join(SCENES), help="comma-separated subset of %s" % ", ".join(SCENES))
    p.add_argument("--integrators", default=",".join(INTEGRATORS))
    p.add_argument("--burn-in", type=int, default=8, help="burn_in of stochastic_ray and ray_bundle")
    p.add_argument("--sr-iterations", type=int, default=64, help="stochastic_ray steps per chain")
    p.add_argument("--bundle-resolution", type=int, default=32, help="ray_bundle lines per side")
    p.add_argument("--bundle-chains", type=int, default=64, help="ray_bundle chains run in lockstep")
    p.add_argument("--bundle-estimate", choices=("gather", "patch"), default="gather", help="ray_bundle image estimate")
    p.add_argument("--room-cells", type=int, default=8, help="quads per wall side in the room")
    p.add_argument("--room-mesh", choices=("conforming", "overlapping"), default="conforming",
                   help="conforming: the floor has no triangles under the blocks (default); overlapping: the "
                        "older room, rotated blocks standing on whole floor quads")
    p.add_argument("--ref-spp", type=int, default=None, help="room reference spp (default 131072, quick 4096)")
    p.add_argument("--max-points", type=int, default=14, help="most budgets per curve")
    p.add_argument("--min-points", type=int, default=None, help="fewest budgets per curve (default 3, quick 2)")
    p.add_argument("--repeats", type=int, default=2,
                   help="renders (seeds) per budget; their RMS error is the budget's RMSE (default 2)")
    p.add_argument("--out", default=os.path.join(HERE, "stochastic_iteration.png"))
    p.add_argument("--no-isolate", dest="isolate", action="store_false",
                   help="run all integrators in this process, ladders interleaved (default: one fresh process per "
                        "integrator and scene; a Dr.Jit integrator renders 20-25 %% slower in a process where "
                        "Mitsuba's C++ path has rendered, measured 1.15 s -> 1.40 s, and more after several)")
    p.add_argument("--no-gather-nee", dest="gather_nee", action="store_false",
                   help="ray_bundle_avg with gather_nee=false (direct light in the patch average)")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    seconds = args.seconds or (0.3 if args.quick else 2.5)
    ref_spp = args.ref_spp or (4096 if args.quick else 131072)
    names = [s for s in args.scenes.split(",") if s]
    inames = [s for s in args.integrators.split(",") if s]
    for s in names:
        if s not in SCENES:
            p.error("unknown scene %r; choose from %s" % (s, ", ".join(SCENES)))
    for s in inames:
        if s not in INTEGRATORS:
            p.error("unknown integrator %r; choose from %s" % (s, ", ".join(INTEGRATORS)))

    t_start = time.perf_counter()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    meths = {k: v for k, v in methods(args).items() if k in inames}
    if args.worker:
        names = [args.worker.split(":")[0]]
    scenes = make_scenes(names, args.resolution, args.room_cells, ref_spp, args.room_mesh == "conforming")
    min_points = args.min_points or (2 if args.quick else 3)

    def measure(case, meths):
        """Ladders (interleaved), then ray counts: {integrator: curve}, {integrator: rays}, {integrator: how}."""
        curves = run_scene(case, meths, seconds, args.max_points, min_points, args.repeats)
        rays, how = {}, {}
        for mname, m in meths.items():
            rays[mname], how[mname] = count_rays(case, m, [pt["budget"] for pt in curves[mname]])
        return curves, rays, how

    if args.worker:
        sname, mname = args.worker.split(":")
        curves, rays, how = measure(scenes[sname], {mname: meths[mname]})
        print(WORKER_MARK + json.dumps(dict(curves=curves[mname], rays=rays[mname], how=how[mname])))
        return

    def run_isolated(sname, mname):
        """One integrator's ladder and ray count on one scene, in a fresh process."""
        out = subprocess.run([sys.executable, os.path.abspath(__file__), *sys.argv[1:], "--worker",
                              "%s:%s" % (sname, mname)], capture_output=True, text=True)
        lines = [l for l in out.stdout.splitlines() if l.startswith(WORKER_MARK)]
        if out.returncode != 0 or not lines:
            raise RuntimeError("worker %s:%s failed:\n%s\n%s" % (sname, mname, out.stdout[-2000:], out.stderr[-4000:]))
        data = json.loads(lines[-1][len(WORKER_MARK):])
        return data["curves"], {int(b): n for b, n in data["rays"].items()}, data["how"]
    print("stochastic_ray: iterations %d, burn_in %d; ray_bundle: burn_in %d, resolution %d, chains %d, estimate %s (ray_bundle_fs: the same with first_shot=true; ray_bundle_avg: first_shot=true, average_diffuse=true); ladders "
          "double until a render takes %.2f s, %d render(s) per budget; %d x %d px, llvm_ad_rgb, %d threads\n"
          % (args.sr_iterations, args.burn_in, args.burn_in, args.bundle_resolution, args.bundle_chains, args.bundle_estimate, seconds,
             args.repeats, args.resolution,
             args.resolution, dr.thread_count()))
    results, warns, notes = {}, [], []
    for sname, case in scenes.items():
        t0 = time.perf_counter()
        if args.isolate:
            curves, rays, how = {}, {}, {}
            for mname in meths:
                curves[mname], rays[mname], how[mname] = run_isolated(sname, mname)
        else:
            curves, rays, how = measure(case, meths)
        for mname in meths:
            warns += monotone_warnings(sname, mname, curves[mname])
        print("  [%s: %d renders and ray counting in %.1f s%s]"
              % (sname, sum(len(c) for c in curves.values()), time.perf_counter() - t0,
                 ", one process per integrator" if args.isolate else ""), flush=True)
        t_star = min(c[-1]["seconds"] for c in curves.values())
        results[sname] = dict(curves=curves, rays=rays, how=how, t_star=t_star)
        report_scene(sname, case, results[sname], meths, notes)
    summary(results, meths)
    for line in warns:
        print(line)
    if notes:
        print()
        for line in notes:
            print(line)
    plot(results, scenes, args)
    print("total run time %.1f s" % (time.perf_counter() - t_start))



if __name__ == "__main__":
    main()
