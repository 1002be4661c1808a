"""Analysis, report and plot of the stochastic-iteration benchmark's curves.

A curve is one integrator's ladder on one scene, ``[dict(budget, seconds, compile,
rmse, mean), ...]`` (see `stochastic_iteration.py`'s ``run_scene``). This module
interpolates curves at equal time (:func:`interp_loglog`), fits their log-log slope,
derives rays per second, prints the per-scene tables and the issue-4 summary, and
writes the log-log plot. Scene names come from scenes.py (import after
``mi.set_variant('llvm_ad_rgb')``, as the driver does). Run the benchmark from the
repository root:

    python3 benchmarks/stochastic_iteration.py --quick --scenes furnace
"""
import math
import os

import numpy as np

from scenes import DIFFUSE_SCENES, SHORT, SIERPINSKI


# ---------------------------------------------------------------------------- curves
def interp_loglog(points, t):
    """RMSE of a curve at time t (piecewise linear in log-log); outside the curve's range,
    extrapolated with slope -1/2 from the nearest end, flagged by the second value."""
    ts = np.log([p["seconds"] for p in points])
    es = np.log([p["rmse"] for p in points])
    order = np.argsort(ts)
    ts, es = ts[order], es[order]
    lt = math.log(t)
    if lt < ts[0]:
        return math.exp(es[0] - 0.5 * (lt - ts[0])), True
    if lt > ts[-1]:
        return math.exp(es[-1] - 0.5 * (lt - ts[-1])), True
    return math.exp(float(np.interp(lt, ts, es))), False


def slope(points):
    if len(points) < 2:
        return float("nan")
    return float(np.polyfit(np.log([p["seconds"] for p in points]), np.log([p["rmse"] for p in points]), 1)[0])


def monotone_warnings(scene, name, points):
    out = []
    for a, b in zip(points, points[1:]):
        if b["rmse"] >= a["rmse"]:
            out.append("WARNING %s / %s: RMSE does not decrease from budget %d (%.4g) to %d (%.4g)"
                       % (scene, name, a["budget"], a["rmse"], b["budget"], b["rmse"]))
    return out


def rays_per_second(points, rays):
    """Rays per second of a curve: the better of its two largest renders (robust to a
    load spike from other processes; small renders are dominated by fixed overheads)."""
    return max(rays[p["budget"]] / p["seconds"] for p in points[-2:])


# ---------------------------------------------------------------------------- report
def report_scene(sname, case, res, meths, notes):
    exact = case.expected()
    exact_mean = float(np.mean(exact))
    curves, t_star = res["curves"], res["t_star"]
    base_rmse = interp_loglog(curves["path"], t_star)[0] if "path" in curves else None
    base_rate = None
    if "path" in curves:
        base_rate = rays_per_second(curves["path"], res["rays"]["path"])
    print("\n%s (%s)%s; equal time t* = %.2f s" % (sname, SHORT[sname], "" if sname != "room" else
          ", RMSE vs reference (its noise %.4f removed)" % case.reference_noise, t_star))
    print("%-15s %13s %7s %9s %8s %8s %7s %9s %7s %9s %7s %8s" % (
        "integrator", "budgets", "seconds", "RMSE", "mean", "exact", "slope", "RMSE@t*", "/path",
        "Mrays/s", "/path", "compile"))
    for mname, pts in curves.items():
        last = pts[-1]
        at, extrap = interp_loglog(pts, t_star)
        rate = rays_per_second(pts, res["rays"][mname])
        budgets = "%d-%d %s" % (pts[0]["budget"], last["budget"], "spp" if meths[mname].budget_label == "spp" else "it")
        print("%-15s %13s %7.2f %9.5f %8.4f %8.4f %7.2f %8.5f%s %7s %9.2f %7s %7.1fs" % (
            mname, budgets, last["seconds"], last["rmse"], last["mean"], exact_mean, slope(pts), at,
            "*" if extrap else " ", "%.3f" % (at / base_rmse) if base_rmse else "-", rate / 1e6,
            "%.2f" % (rate / base_rate) if base_rate else "-", sum(p["compile"] for p in pts)))
    for mname in curves:
        extra = ""
        if mname.startswith("ray_bundle"):
            last = curves[mname][-1]
            extra = "; %.1f ms per iteration" % (1e3 * last["seconds"] / last["budget"])
        notes.append("rays %s / %s: %s%s" % (sname, mname, res["how"][mname], extra))


def summary(results, meths):
    if "path" not in meths:
        return
    print("\nTargets: beat path at equal time on the diffuse closed scenes; >= 1/2 of path's rays/s")
    print("%-30s %-15s %12s %10s" % ("scene", "integrator", "RMSE/path@t*", "rays/s/path"))
    for sname, res in results.items():
        curves = res["curves"]
        base = interp_loglog(curves["path"], res["t_star"])[0]
        base_rate = rays_per_second(curves["path"], res["rays"]["path"])
        for mname in ("ray_bundle", "ray_bundle_fs", "ray_bundle_avg", "stochastic_ray"):
            if mname not in curves:
                continue
            pts = curves[mname]
            ratio = interp_loglog(pts, res["t_star"])[0] / base
            rate = rays_per_second(pts, res["rays"][mname]) / base_rate
            tag = "" if sname in DIFFUSE_SCENES else " (not a diffuse target)"
            print("%-30s %-15s %8.3f %-3s %8.2f %-3s%s" % (sname, mname, ratio, "ok" if ratio < 1 else "NO",
                                                          rate, "ok" if rate >= 0.5 else "NO", tag))


# ---------------------------------------------------------------------------- plot
def plot(results, scenes, args):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401
    panels = list(scenes) + (["figure4"] if any(s in results for s in SIERPINSKI) else [])
    cols = 3
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.0 * cols, 4.0 * rows), squeeze=False)
    colors = {"path": "C0", "ptracer": "C1", "stochastic_ray": "C2", "ray_bundle": "C3", "ray_bundle_fs": "C4",
              "ray_bundle_avg": "C5"}
    for ax, panel in zip(axes.flat, panels):
        if panel == "figure4":
            for s, style in zip(SIERPINSKI, ("-o", "--s", ":^")):
                if s in results and "ray_bundle" in results[s]["curves"]:
                    pts = results[s]["curves"]["ray_bundle"]
                    ax.loglog([p["budget"] for p in pts], [p["rmse"] for p in pts], style, ms=3, label=SHORT[s])
            ax.set_xscale("log", base=2)
            ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_xlabel("ray_bundle iterations (burn-in included)")
            ax.set_title("paper fig. 4: ray_bundle error, Sierpinski scenes", fontsize=10)
        else:
            for name, pts in results[panel]["curves"].items():
                ax.loglog([p["seconds"] for p in pts], [p["rmse"] for p in pts], "-o", ms=3, color=colors[name],
                          label=name)
            ax.axvline(results[panel]["t_star"], color="0.7", lw=0.8, ls="--")
            ax.set_xlabel("seconds (compile time excluded)")
            ax.set_title(SHORT[panel], fontsize=10)
        ax.set_ylabel("RMSE")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.suptitle("Error versus wall time, %d x %d px (%s)" % (args.resolution, args.resolution,
                                                               "quick" if args.quick else "default"))
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print("plot: %s" % args.out)
