"""``mi-plugins demo``: what the package renders, in pictures, in under two minutes.

1. **One view at equal time**: Mitsuba's Cornell box with Mitsuba's ``path`` and the
   package's ``stochastic_ray``, ``ray_bundle`` and ``qmc_lighttrace`` (each repeats
   independent renders until its seconds are spent and averages them), and the smooth
   display of the view-independent solutions of ``ray_bundle`` and ``qmc_lighttrace``
   (one solve for ``timesplit.SOLVE_SHARE['view']`` of the seconds, then the camera
   samples that fit in the rest). Every row on a fresh scene object, its kernels compiled
   on another first. One PNG per image and a contact sheet with each image's error
   against a long ``path`` reference (cached on disk), whole image and away from the lamp.
2. **A walkthrough** (``mi_plugins.app.walkthrough``): a camera path through the box rendered
   by ``path`` and from one solve of each solution integrator in the same total time,
   each frame's error printed, an animated GIF side by side and a contact strip, and the
   time each solution needs to reach ``path``'s error on every frame.
3. A short analytic check (a few cases with exactly known radiance) and its PASS/FAIL lines.
"""
import os
import time

import mitsuba as mi
import numpy as np

from mi_plugins.app import animation, cached_references, timesplit, walkthrough
from mi_plugins.app.animation import to_srgb8
from mi_plugins.app.cached_references import away_from_light  # noqa: F401  (the demo's lamp mask, used by the benchmarks)

#: the integrators of the demo and their settings (the package's defaults; the smooth
#: displays' solve sized by the seconds: mi_plugins.app.timesplit)
INTEGRATORS = {
    "path": {"type": "path"},
    "stochastic_ray": {"type": "stochastic_ray"},
    "ray_bundle": {"type": "ray_bundle"},
    "qmc_lighttrace": {"type": "qmc_lighttrace"},
    "ray_bundle smooth": {"type": "ray_bundle", "display": "smooth"},
    "qmc_lighttrace smooth": {"type": "qmc_lighttrace", "display": "smooth"},
}
#: spp of one render of each (a render is repeated until the integrator's seconds are spent)
SPP = {"path": 16, "stochastic_ray": 1, "ray_bundle": 1, "qmc_lighttrace": 8}
#: the reference's samples per pixel (path, cached on disk)
REFERENCE_SPP = 4096
#: the analytic check: (case, integrator dict, spp, runs)
CHECKS = [("furnace_box", {"type": "path"}, 8, 16),
          ("furnace_box", {"type": "stochastic_ray"}, 2, 16),
          ("keller_cube", {"type": "qmc_lighttrace", "samples": 20000}, 8, 16),
          ("furnace_box", {"type": "ray_bundle", "chains": 16, "resolution": 16, "iterations": 16, "burn_in": 8}, 1, 16)]


def cornell(resolution):
    d = mi.cornell_box()
    d.pop("integrator", None)
    d["sensor"]["film"].update(width=int(resolution), height=int(resolution))
    return d


def equal_time(scene, integrator, spp, seconds, seed=0):
    """Average of independent renders until ``seconds`` are spent: (image, renders, seconds)."""
    integ = mi.load_dict(integrator)
    total, count, t0 = None, 0, time.perf_counter()
    while count == 0 or time.perf_counter() - t0 < seconds:
        image = np.array(mi.render(scene, integrator=integ, spp=spp, seed=seed * 1000 + count), dtype=np.float64)
        total = image if total is None else total + image
        count += 1
    return total / count, count, time.perf_counter() - t0


def write_png(path, image):
    mi.Bitmap(to_srgb8(image), pixel_format=mi.Bitmap.PixelFormat.RGB).write(path)


def contact_sheet(path, entries):
    """``entries``: [(title, image)]; a side-by-side sheet with titles (matplotlib), or the
    images tiled without titles where matplotlib is not installed."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        write_png(path, np.concatenate([image for _, image in entries], axis=1))
        return
    fig, axes = plt.subplots(1, len(entries), figsize=(3.2 * len(entries), 3.9))
    for ax, (title, image) in zip(np.atleast_1d(axes), entries):
        ax.imshow(to_srgb8(image), interpolation="nearest")
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def stills(out_dir, seconds, resolution, rates, out, cache=None):
    """Part 1: every integrator on the box's own view at equal ``seconds``."""
    d = cornell(resolution)
    reference = cached_references.path_references(d, REFERENCE_SPP, tag="demo", cache=cache, out=out)[0]
    write_png(os.path.join(out_dir, "reference_path.png"), reference.image)
    out("Cornell box, %d x %d px, %.0f s per integrator (equal time; RMSE relative to the image mean, the "
        "reference's noise taken out)" % (resolution, resolution, seconds))
    entries = []
    for name, integrator in INTEGRATORS.items():
        if "display" in integrator:
            image, info = timesplit.solve_and_display(mi.load_dict(d), rates[integrator["type"]], seconds)
            spent = info["seconds"]
            how = "%d solve (%s %d, %.1f s), %d spp" % (info["solves"], rates[integrator["type"]].name, info["size"],
                                                      info["solve_seconds"], info["spp"])
        else:
            mi.render(mi.load_dict(d), integrator=mi.load_dict(integrator), spp=1, seed=999)   # compile
            image, renders, spent = equal_time(mi.load_dict(d), integrator, SPP[name], seconds)
            how = "%d renders" % renders
        full, away = reference.errors(image)
        write_png(os.path.join(out_dir, name.replace(" ", "_") + ".png"), image)
        entries.append(("%s\nRMSE %.1f %% (away from the lamp %.2f %%), %.1f s" % (name, 100 * full, 100 * away,
                                                                                 spent), image))
        out("  %-22s %-41s %5.1f s  RMSE %4.1f %%, away from the lamp %5.2f %%" % (name, how, spent, 100 * full,
                                                                                   100 * away))
    entries.append(("reference: path\n%d spp" % REFERENCE_SPP, reference.image))
    sheet = os.path.join(out_dir, "contact_sheet.png")
    contact_sheet(sheet, entries)
    out("wrote %s and one PNG per integrator in %s" % (sheet, out_dir))


def walk_pictures(out_dir, walk, out):
    """The walkthrough's animated GIF (path and each solution side by side) and its strip."""
    why = animation.available()
    if why is not None:
        out("walkthrough animation and strip skipped: %s" % why)
        return
    columns = [(run.images, [[name, "1 solve, %d spp a frame" % run.info["spp"] if run.info else run.how,
                              "%.1f s: RMSE %.1f %%" % (run.seconds, 100 * e)] for e in run.errors[:, 0]])
               for name, run in walk.runs.items()]
    gif = os.path.join(out_dir, "walkthrough.gif")
    animation.write_animation(gif, columns)
    picks = sorted(set(np.linspace(0, len(walk.transforms) - 1, 5).round().astype(int).tolist()))
    rows = [("reference: path %d spp" % (walkthrough.REFERENCE_FACTOR * walkthrough.PATH_SPP),
             [r.image for r in walk.refs], [["frame %d" % k] for k in range(len(walk.refs))])]
    rows += [("%s: %s, %.1f s in all" % (name, run.how, run.seconds), run.images,
              [["%.1f %%" % (100 * e)] for e in run.errors[:, 0]]) for name, run in walk.runs.items()]
    strip = os.path.join(out_dir, "walkthrough_strip.png")
    animation.write_strip(strip, rows, picks)
    out("wrote %s (%d frames) and %s" % (gif, len(walk.transforms), strip))


def check_settings(seconds, resolution, frames):
    """Refuse settings the demo cannot use, naming the value and the valid range."""
    if not float(seconds) > 0:
        raise ValueError("mi-plugins demo: seconds=%r: valid: more than 0" % (seconds,))
    if int(resolution) < 8:
        raise ValueError("mi-plugins demo: resolution=%r: valid: 8 or more pixels per side" % (resolution,))
    if int(frames) != 0 and int(frames) < 2:
        raise ValueError("mi-plugins demo: frames=%r: valid: 0 (no walkthrough) or 2 or more" % (frames,))


def run(out_dir="reports/demo", seconds=5.0, resolution=128, check=True, out=print, frames=walkthrough.FRAMES,
        cache=None, rates=None):
    """Part 1, the walkthrough (``frames`` > 0) and the checks; writes into ``out_dir``;
    returns 0 when every check passes. ``rates``: {integrator: timesplit.SolveRate} (None:
    measured here, which also compiles the solutions' kernels); ``cache``: the references'
    folder (None: cached_references.CACHE)."""
    check_settings(seconds, resolution, frames)
    os.makedirs(out_dir, exist_ok=True)
    t0 = time.perf_counter()
    if rates is None:
        rates = {name: timesplit.SolveRate.measure(lambda: mi.load_dict(cornell(resolution)),
                                                   {"type": name, "display": "smooth"}, seed=9)
                 for name in ("ray_bundle", "qmc_lighttrace")}
    stills(out_dir, seconds, resolution, rates, out, cache)
    if frames:
        out("")
        walk = walkthrough.compare(resolution, {name: rates[name] for name in ("qmc_lighttrace", "ray_bundle")
                                                if name in rates}, frames=frames, cache=cache, out=out)
        walk_pictures(out_dir, walk, out)
    out("rendering: %.0f s in all" % (time.perf_counter() - t0))
    if not check:
        return 0
    from mi_plugins.verify import analytic
    out("\nanalytic check (exactly known radiance):")
    failed = 0
    for case_name, integrator, spp, runs in CHECKS:
        case = analytic.cases()[case_name](resolution=16)
        res = analytic.check(case, integrator, spp=spp, runs=runs, seed=1)
        failed += not res.passed
        out("  %-4s %-12s %-15s mean %.5f exact %.5f (z %+.2f, %.1f s)" % (
            "PASS" if res.passed else "FAIL", case_name, integrator["type"], res.mean, res.expected_mean, res.z,
            res.seconds))
    return 1 if failed else 0
