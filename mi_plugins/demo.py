"""``mi-plugins demo``: what the package renders, in pictures, in about a minute.

Renders Mitsuba's Cornell box with Mitsuba's ``path`` and the package's
``stochastic_ray``, ``ray_bundle`` and ``qmc_lighttrace`` at equal time (each repeats
independent renders until its share of seconds is spent and averages them), and the
smooth display of the view-independent solutions of ``ray_bundle`` and
``qmc_lighttrace`` (one solve, then camera samples until the same seconds are spent),
writes one PNG per image and a contact sheet with each image's error against a longer
``path`` reference (on the whole image and away from the visible lamp) and its time,
then runs a short analytic check (a few cases with exactly known radiance, a few
integrators) and prints PASS/FAIL lines.
"""
import os
import time

import mitsuba as mi
import numpy as np

#: the integrators of the demo and their settings (the package's defaults where they are quick)
INTEGRATORS = {
    "path": {"type": "path"},
    "stochastic_ray": {"type": "stochastic_ray"},
    "ray_bundle": {"type": "ray_bundle"},
    "qmc_lighttrace": {"type": "qmc_lighttrace"},
    # one solve each (a longer one than the defaults: its noise stays in every camera sample),
    # then the solution shown with as many camera samples as the seconds allow
    "ray_bundle smooth": {"type": "ray_bundle", "display": "smooth", "iterations": 64},
    "qmc_lighttrace smooth": {"type": "qmc_lighttrace", "display": "smooth", "samples": 1600000},
}
#: spp of one render of each (a render is repeated until the integrator's seconds are spent)
SPP = {"path": 16, "stochastic_ray": 1, "ray_bundle": 1, "qmc_lighttrace": 8}
#: the first spp of a solution display (doubled while the seconds allow)
DISPLAY_SPP = 4
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


def equal_time_display(scene, integrator, seconds, seed=0):
    """One solve, then the solution displayed with twice the camera samples per render
    while the next render fits into ``seconds`` (same seed: the solution is kept):
    (image of the last render, its spp, seconds, solves)."""
    integ = mi.load_dict(integrator)
    spp, t0 = DISPLAY_SPP, time.perf_counter()
    while True:
        start = time.perf_counter()
        image = np.array(mi.render(scene, integrator=integ, spp=spp, seed=seed), dtype=np.float64)
        now = time.perf_counter()
        if now - t0 + 2.2 * (now - start) > seconds:
            return image, spp, now - t0, integ.solve_count
        spp *= 2


def away_from_light(reference):
    """Pixels none of whose 3 x 3 neighbours sees the lamp (reference above 1 in a channel:
    the lamp emits 18.4, the brightest lit wall pixels stay below 0.5)."""
    lit = np.pad(reference[..., :3].max(axis=-1) > 1.0, 1)
    h, w = reference.shape[:2]
    return ~np.any([lit[i:i + h, j:j + w] for i in range(3) for j in range(3)], axis=0)


def to_srgb8(image):
    rgb = np.clip(image[..., :3], 0, None)
    srgb = np.where(rgb <= 0.0031308, 12.92 * rgb, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    return (np.clip(srgb, 0, 1) * 255 + 0.5).astype(np.uint8)


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


def run(out_dir="reports/demo", seconds=8.0, resolution=64, check=True, out=print):
    """Render, write the PNGs and the contact sheet into ``out_dir``, run the checks;
    returns 0 when every check passes."""
    os.makedirs(out_dir, exist_ok=True)
    scene = mi.load_dict(cornell(resolution))
    out("Cornell box, %d x %d px, %.0f s per integrator (equal time)" % (resolution, resolution, seconds))
    reference, refs, ref_seconds = equal_time(scene, INTEGRATORS["path"], 256, 3 * seconds, seed=99)
    write_png(os.path.join(out_dir, "reference_path.png"), reference)
    entries = []
    away, mean = away_from_light(reference), max(float(np.mean(reference[..., :3])), 1e-12)
    for name, integrator in INTEGRATORS.items():
        if "display" in integrator:
            image, spp, spent, solves = equal_time_display(scene, integrator, seconds)
            how = "%d solve%s, %d spp" % (solves, "" if solves == 1 else "s", spp)
        else:
            image, renders, spent = equal_time(scene, integrator, SPP[name], seconds)
            how = "%d renders" % renders
        err = (image[..., :3] - reference[..., :3]) ** 2
        rel, rel_away = np.sqrt(err.mean()) / mean, np.sqrt(err[away].mean()) / mean
        write_png(os.path.join(out_dir, name.replace(" ", "_") + ".png"), image)
        entries.append(("%s\nRMSE %.1f %% (away from the lamp %.1f %%), %.1f s" % (name, 100 * rel, 100 * rel_away,
                                                                                spent), image))
        out("  %-22s %-17s %5.1f s  RMSE %4.1f %%, away from the lamp %4.1f %% (of the image mean)"
            % (name, how, spent, 100 * rel, 100 * rel_away))
    entries.append(("reference: path\n%d x 256 spp, %.0f s" % (refs, ref_seconds), reference))
    sheet = os.path.join(out_dir, "contact_sheet.png")
    contact_sheet(sheet, entries)
    out("wrote %s and one PNG per integrator in %s" % (sheet, out_dir))
    if not check:
        return 0
    from mi_plugins import analytic
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
