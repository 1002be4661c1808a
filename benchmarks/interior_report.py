"""Statistics and tables of the interior benchmark (`interior_bench.py`).

A method's result on a scene is ``dict(rungs=[dict(budget, spp, renders=[dict(seed,
seconds, seconds_nc, rmse, rmse_x, ...)], bias, noise, ...)], setup=..., status=...)``.
Each seed's renders form a curve (seconds, RMSE) in budget order; a method's RMSE at an
equal time T is read where the curve first reaches T (:func:`at`: piecewise linear in
log-log between the budgets around it, as `analysis.interp_loglog`, which it equals on a
curve whose seconds grow with the budget; past the last render extrapolated with slope
-1/2, flagged '*'; before the first image: '-'). The ratio to `path` is taken seed by
seed against the best sampler's curve of the same seed number; the tables show the
median and the range over seeds.
"""
import math

import numpy as np

from analysis import interp_loglog

PATHS = ("path_independent", "path_stratified", "path_multijitter", "path_orthogonal", "path_ldsampler")


# ---------------------------------------------------------------------------- one render, one rung
def errors(image, ref, ref_var, keep):
    """(RMSE, RMSE on the pixels ``keep``) against ``ref``, the reference's own noise
    (per-pixel variance ``ref_var``) removed (the correction capped at halving the RMSE)."""
    e = np.mean((image - ref) ** 2, axis=-1)
    out = []
    for m in (Ellipsis, keep):
        raw, var = float(np.mean(e[m])), float(np.mean(ref_var[m]))
        out.append(math.sqrt(max(raw - var, 0.25 * raw, 1e-30)))
    return out


def split(images, ref, ref_var, keep):
    """Bias and noise of one budget's renders (one per seed, at least 2): noise^2 = the
    pixels' mean variance over seeds (one render's noise); bias^2 = MSE of the seeds' mean
    - noise^2 / seeds - the reference's noise^2 (0 where negative); full image and ``keep``.
    ``bias2_se`` (and ``_x``): the standard error of that bias^2 estimate, from its
    per-pixel terms (the mean over pairs of seeds of their errors' product, less the
    reference's noise^2) taken as independent: near emitters these terms are heavy-tailed
    (a lamp's edge pixels), and with 2 seeds a bias of 0.4 % of the image mean can carry
    an SE of a third of its square; the spatial correlation of the errors makes the true
    SE larger still."""
    a = np.stack(images)
    n = len(a)
    var = np.mean(np.var(a, axis=0, ddof=1), axis=-1)
    mse = np.mean((a.mean(axis=0) - ref) ** 2, axis=-1)
    rv = np.mean(ref_var, axis=-1) if ref_var.ndim == 3 else ref_var
    terms = mse - var / n - rv            # per pixel: an unbiased estimate of its bias^2
    out = {}
    for suffix, m in (("", Ellipsis), ("_x", keep)):
        noise2 = float(np.mean(var[m]))
        out["noise" + suffix] = math.sqrt(noise2)
        out["bias" + suffix] = math.sqrt(max(float(np.mean(mse[m])) - noise2 / n - float(np.mean(rv[m])), 0.0))
        t = terms[m].ravel()
        out["bias2_se" + suffix] = float(np.std(t, ddof=1) / math.sqrt(t.size))
    out["mean_rel"] = float(a.mean() / ref.mean())
    return out


def bias_range(parts, suffix="", z=2.0):
    """(low, high): the bias of :func:`split` at -z and +z standard errors of its square
    (0 where the square's bound is negative)."""
    b2, se = parts["bias" + suffix] ** 2, parts["bias2_se" + suffix]
    return math.sqrt(max(b2 - z * se, 0.0)), math.sqrt(max(b2 + z * se, 0.0))


# ---------------------------------------------------------------------------- curves at equal time
def seeds_of(res):
    return sorted({r["seed_index"] for rung in res.get("rungs", []) for r in rung["renders"]})


def curve(res, seed_index, key, tkey="seconds"):
    return [dict(seconds=r[tkey], rmse=r[key]) for rung in res.get("rungs", []) for r in rung["renders"]
            if r["seed_index"] == seed_index]


def at(res, seed_index, key, t, tkey="seconds_nc"):
    """(RMSE at time t, extrapolated) of one seed's curve where its seconds first reach t;
    None before its first image. ``tkey``: 'seconds_nc' (wall clock, the kernel
    compilation inside the render subtracted) or 'seconds' (wall clock)."""
    pts = curve(res, seed_index, key, tkey)
    if not pts or t < min(p["seconds"] for p in pts):
        return None
    for a, b in zip(pts, pts[1:]):
        if a["seconds"] <= t <= b["seconds"]:
            return interp_loglog([a, b], t)
    if t <= max(p["seconds"] for p in pts):      # (a render slower than a later one: the last one before it)
        return interp_loglog([max((p for p in pts if p["seconds"] <= t), key=lambda p: p["seconds"])], t)
    return interp_loglog(pts[-1:], t)


def best_path(results, times, key="rmse", tkey="seconds_nc"):
    """The `path` sampler with the lowest geometric mean over ``times`` of its median RMSE over
    seeds (None if no path sampler ran), and every sampler's score."""
    scores = {}
    for name in PATHS:
        res = results.get(name)
        if not res or not res.get("rungs"):
            continue
        logs = []
        for t in times:
            vals = [at(res, s, key, t, tkey) for s in seeds_of(res)]
            vals = [v[0] for v in vals if v is not None]
            if vals:
                logs.append(math.log(float(np.median(vals))))
        if logs:
            scores[name] = math.exp(float(np.mean(logs)))
    return (min(scores, key=scores.get) if scores else None), scores


def ratio(res, base, key, t, tkey="seconds_nc"):
    """(median, lowest, highest, any extrapolated) over seeds of RMSE(res) / RMSE(base) at
    time t, or None where either has no image by then."""
    vals, flag = [], False
    for s in seeds_of(res):
        a, b = at(res, s, key, t, tkey), at(base, s, key, t, tkey)
        if a is None or b is None:
            continue
        vals.append(a[0] / b[0])
        flag |= a[1] or b[1]
    if not vals:
        return None
    return float(np.median(vals)), min(vals), max(vals), flag


def first_image(res, tkey="seconds_nc"):
    """Median seconds of the smallest budget's renders."""
    rungs = res.get("rungs") or []
    return float(np.median([r[tkey] for r in rungs[0]["renders"]])) if rungs else None


def timing_spread(res):
    """Median over budgets of (slowest / fastest render - 1) over seeds: how noisy the timings were."""
    rungs = [g for g in res.get("rungs") or [] if len(g["renders"]) > 1]
    return float(np.median([max(r["seconds"] for r in g["renders"]) / min(r["seconds"] for r in g["renders"]) - 1
                            for g in rungs])) if rungs else None


# ---------------------------------------------------------------------------- tables
def fmt_ratio(r):
    if r is None:
        return "-"
    med, lo, hi, flag = r
    return "%.2f%s (%.2f-%.2f)" % (med, "*" if flag else "", lo, hi)


def scene_tables(sname, info, results, times):
    """Markdown lines of one scene: the equal-time ratios (full image, away from emitters),
    the largest budgets, the setup."""
    best, scores = best_path(results, times)
    lines = ["### %s" % sname, "", info, ""]
    if best is None:
        return lines + ["No `path` sampler ran: no ratios.", ""], None
    lines.append("`path`'s sampler, chosen by its RMSE over the equal times (geometric mean of the medians; "
                 "lower is better): " + ", ".join("%s %.4g%s" % (n[5:], v, " (best)" if n == best else "")
                                                  for n, v in sorted(scores.items(), key=lambda kv: kv[1])) + ".")
    lines.append("")
    head = "| method | first image (s) | " + " | ".join("RMSE / path at %g s" % t for t in times) + " |"
    ratios = {}
    for key, tkey, title in (("rmse", "seconds_nc", "Full image"),
                             ("rmse_x", "seconds_nc", "Away from emitters (pixels not seeing one, 3 x 3)"),
                             ("rmse", "seconds", "Full image, wall clock with the kernel compilation inside the "
                                                 "timed renders")):
        lines += ["%s: RMSE ratio to `path` (%s) at equal time, median (range) over seeds." % (title, best[5:]), "",
                  head, "|---|---:|" + "---:|" * len(times)]
        for name, res in results.items():
            if not res.get("rungs"):
                lines.append("| %s | %s |%s" % (name, res.get("status") or "failed", " |" * len(times)))
                continue
            row = [ratio(res, results[best], key, t, tkey) for t in times]
            ratios.setdefault(name, {})[key + ("" if tkey == "seconds_nc" else "_wall")] = row
            lines.append("| %s | %.2f | %s |" % (name, first_image(res, tkey), " | ".join(fmt_ratio(r) for r in row)))
        lines.append("")
    lines += ["The largest budget of each method (all seeds): wall-clock seconds median (range), RMSE, bias and one "
              "render's noise, full image and away from emitters; image mean relative to the reference; "
              "timing spread: median over budgets of slowest / fastest seed - 1.", "",
              "| method | budgets | seconds | RMSE | bias | noise | RMSE away | bias away | noise away | mean rel. "
              "| timing spread |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, res in results.items():
        if not res.get("rungs"):
            continue
        rungs, last = res["rungs"], res["rungs"][-1]
        sec = [r["seconds"] for r in last["renders"]]
        lines.append("| %s | %s-%s spp%s | %.1f (%.1f-%.1f) | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g | %.4f | %s |" % (
            name, rungs[0]["spp"], last["spp"], " (%s)" % res["stopped"] if res.get("stopped") else "",
            np.median(sec), min(sec), max(sec), np.median([r["rmse"] for r in last["renders"]]), last["bias"],
            last["noise"], np.median([r["rmse_x"] for r in last["renders"]]), last["bias_x"], last["noise_x"],
            last["mean_rel"], "%.0f %%" % (100 * timing_spread(res)) if timing_spread(res) is not None else "-"))
    lines += [""]
    setups = [(n, r) for n, r in results.items() if r.get("setup")]
    if setups:
        lines += ["Setup of the package's integrators on a freshly loaded scene (kernels warm): the patch table "
                  "(subdivision, clustering, dark splits) and the smooth display's field; the smallest budget's "
                  "render (all of it) and, for the displays, its solve.", "",
                  "| method | patches | patch table (s) | field (s) | first image (s) | its solve (s) "
                  "| compiled in it (s) |", "|---|---:|---:|---:|---:|---:|---:|"]
        for name, res in setups:
            s = res["setup"]
            solve = [r.get("solve_s") for r in res["rungs"][0]["renders"]] if res.get("rungs") else []
            solve = [x for x in solve if x is not None]
            compiled = [r.get("compile_s", 0.0) for r in res["rungs"][0]["renders"]] if res.get("rungs") else []
            lines.append("| %s | %s | %.2f | %s | %s | %s | %s |" % (
                name, s.get("patches", "-"), s["patch_table_s"], "%.2f" % s["field_s"] if s.get("field_s") else "-",
                "%.2f" % first_image(res) if res.get("rungs") else "-",
                "%.2f" % float(np.median(solve)) if solve else "-",
                "%.2f" % float(np.median(compiled)) if compiled else "-"))
        lines.append("")
    return lines, (best, ratios)


def family_lines(per_scene, times):
    """The family's medians: for each method, the median over scenes of its per-scene median
    ratio (full image / away from emitters / full image by the wall clock, compilation included)."""
    methods = [m for m in dict.fromkeys(m for _, r in per_scene.values() for m in r) if not m.startswith("path")]
    lines = ["| method | " + " | ".join("%g s" % t for t in times) + " |", "|---|" + "---:|" * len(times)]
    for m in methods:
        cells = []
        for k in range(len(times)):
            vals = [[r[m][key][k][0] for _, r in per_scene.values() if m in r and r[m][key][k] is not None]
                    for key in ("rmse", "rmse_x", "rmse_wall")]
            cells.append(" / ".join("%.2f" % float(np.median(v)) if v else "-" for v in vals)
                         + " (%d)" % len(vals[0]))
        lines.append("| %s | %s |" % (m, " | ".join(cells)))
    return lines
