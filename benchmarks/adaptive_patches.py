"""Patches that follow the light: the patch bias of uniform patches against adaptive
subdivision (`refine`) at the same patch budget, and a picture of both.

The *patch bias* is the error the patches make: `qmc_lighttrace` (whose particles carry
the light between exact positions, so that its patch values are unbiased averages) shown
with `display='patches'` (the flat values: rho / pi times each patch side's irradiance,
direct light included) or, with `--display smooth`, with its smooth display (the direct
light per pixel, the patches' indirect light interpolated from their vertices: the
patches' error as a user of the solution sees it), two seeds, its noise removed, against
a cached long `path` reference (real_scene_meshes.py): RMS per pixel and channel, full
image and away from the visible light. Per scene: uniform patches at four sizes (`dark_levels` 0; a
log-log fit of the bias against the patch count), the defaults (the dark splits), and
`refine` (adaptive subdivision) on top of them; every layout's bias is compared with the
uniform fit at its own patch count. Writes docs/adaptive_patches.png (the smooth
display: docs/adaptive_patches_smooth.png): the patch layouts
(false colours, split patches orange) and the signed error images of the uniform default,
the refined and the finest uniform layout. Run from the
repository root (about three minutes):

    python3 benchmarks/adaptive_patches.py [--scenes cornell_closed,cornell] [--samples 2000000]
        [--display smooth --spp 256]
"""
import argparse
import math
import os
import sys

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402
from mi_plugins.patches import refinement  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:
    sys.path.insert(0, HERE)
import real_scene_meshes as rsm  # noqa: E402

ROOT = os.path.dirname(HERE)
PNG = os.path.join(ROOT, "docs", "adaptive_patches.png")
RES = 128
SEEDS = (0, 1)
#: the uniform layouts' patch sizes, as fractions of the default
UNIFORM_SIZES = (1.0, 0.85, 0.7, 0.55)
ERROR_SCALE = 0.05      # signed error shown at full colour (red: too bright, blue: too dark)


def patch_ids(scene, table):
    """Per pixel (pixel centres, the scene's sensor): the patch a camera ray hits, -1 on a miss."""
    sensor = scene.sensors()[0]
    idx = dr.arange(mi.UInt32, RES * RES)
    pos = mi.Vector2f(mi.Float(idx % RES) + 0.5, mi.Float(idx // RES) + 0.5) / RES
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    patch = table.locate(si, si.is_valid())[0]
    return np.where(np.array(si.is_valid()), np.array(patch).astype(np.int64), -1).reshape(RES, RES)


def layout_image(ids, areas):
    """False colours: a hashed grey level per patch, and a hashed orange one for the patches
    smaller than half the median patch (split ones); black where no patch is seen."""
    h = ((ids.astype(np.uint64) * np.uint64(2654435761)) >> np.uint64(8)) & np.uint64(255)
    level = 0.45 + 0.5 * h / 255.0
    small = areas[np.maximum(ids, 0)] < 0.5 * np.median(areas)
    rgb = np.where(small[..., None], level[..., None] * np.array([1.0, 0.55, 0.1]), level[..., None])
    return np.where(ids[..., None] >= 0, rgb, 0.0)


def error_image(err, ref):
    """Signed error (mean over channels) in red / blue over the dimmed reference."""
    e = err.mean(axis=-1) / ERROR_SCALE
    base = 0.35 * np.clip(ref.mean(axis=-1), 0, 1) ** (1 / 2.2)
    return np.clip(np.stack([base + np.clip(e, 0, 1), base, base + np.clip(-e, 0, 1)], axis=-1), 0, 1)


def measure(scene, cfg, ref, ref_var, keep, spp):
    """(patch count, bias full image, bias away from the light, mean error image, (patch ids
    per pixel, patch areas), image mean away from the light relative to the reference)."""
    images, ids, count, areas = [], None, None, None
    for seed in SEEDS:
        integ = mi.load_dict(cfg)
        solution = mi_plugins.solve(scene, integ, seed=seed)
        images.append(np.array(mi.render(scene, integrator=integ, spp=spp, seed=seed), dtype=np.float64)[..., :3])
        if ids is None:
            table = refinement.replay(integ.patch_table(scene), solution.meta.get("refinements"))
            ids, count = patch_ids(scene, table), table.front_count
            areas = np.asarray(table.areas_np[:count], dtype=np.float64)
    mean = 0.5 * (images[0] + images[1])
    noise_var = (images[0] - images[1]) ** 2 / 4.0          # of the mean of the two, per pixel
    e2 = (mean - ref) ** 2 - noise_var - ref_var

    def rms(mask):
        return math.sqrt(max(float(e2[mask].mean()), 0.0))
    return count, rms(np.ones(keep.shape, bool)), rms(keep), mean - ref, (ids, areas), \
        float(mean[keep].mean() / ref[keep].mean())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default="cornell_closed,cornell")
    ap.add_argument("--samples", type=int, default=2_000_000, help="particle paths of each solve")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--ref-spp", type=int, default=16384)
    ap.add_argument("--png", default=None, help="default docs/adaptive_patches.png (the smooth display: "
                                                   "docs/adaptive_patches_smooth.png)")
    ap.add_argument("--display", default="patches", choices=("patches", "smooth"),
                    help="the display measured: the flat patch values, or the smooth display (direct light per "
                         "pixel, the patches' indirect light interpolated: the patches' error as a user sees it)")
    ap.add_argument("--refine", default="", help="extra settings of the refined layout, e.g. refine_threshold=0.05")
    args = ap.parse_args()
    args.png = args.png or (PNG if args.display == "patches" else PNG.replace(".png", "_smooth.png"))
    rows, panels = [], []
    base = dict(type="qmc_lighttrace", display=args.display, samples=args.samples)
    extra = {k: int(v) if v.lstrip("-").isdigit() else float(v)
             for k, v in (kv.split("=") for kv in args.refine.split(",") if kv)}
    print("| scene | layout | patches | patch bias (RMS, full image) | away from the light | image mean (away) | "
          "/ uniform fit at the same count (full / away) |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenes.split(","):
        d, _ = rsm.scene_dict(name, RES)
        scene = mi.load_dict(d)
        ref, ref_var = rsm.reference(name, RES, args.ref_spp)
        keep = rsm.away_from_light(ref)
        default_size = mi.load_dict(base).patch_size_for(scene)
        plain = dict(base, dark_levels=0)
        # uniform patches at several sizes: the patch bias against the patch count (log-log
        # least squares), read at the other layouts' counts
        curve = [(f * default_size, measure(scene, dict(plain, patch_size=f * default_size), ref, ref_var, keep,
                                            args.spp)) for f in UNIFORM_SIZES]
        # (a bias estimated at 0, below the noise it is read under, is left out of the fit)
        fits = [np.polyfit(*np.log([(m[0], m[c]) for _, m in curve if m[c] > 0]).T, 1) for c in (1, 2)]
        at = lambda count, c: math.exp(np.polyval(fits[c - 1], math.log(count)))
        dark = measure(scene, base, ref, ref_var, keep, args.spp)
        refined = measure(scene, dict(base, refine=True, **extra), ref, ref_var, keep, args.spp)
        rows_out = [("uniform, size %.4f (dark_levels 0)" % size, m) for size, m in curve] + \
            [("dark splits (the defaults)", dark), ("dark splits + refine %s" % args.refine, refined)]
        for label, m in rows_out:
            ratio = "%.2f / %.2f" % (m[1] / at(m[0], 1), m[2] / at(m[0], 2))
            print("| %s | %s | %d | %.5f | %.5f | %.4f | %s |" % (name, label, m[0], m[1], m[2], m[5], ratio),
                  flush=True)
        print("| %s | uniform fit: bias ~ patches^%.2f (full image), ^%.2f (away) | | | | | |"
              % (name, fits[0][0], fits[1][0]))
        finest = curve[-1][1]
        panels.append([layout_image(*m[4]) for m in (curve[0][1], refined, finest)] +
                      [error_image(m[3], ref) for m in (curve[0][1], refined, finest)])
    # one row of layouts and one of errors per scene
    gap = np.ones((RES, 4, 3))
    rows = []
    for p in panels:
        rows.append(np.concatenate(sum(([im, gap] for im in p[:3]), [])[:-1], axis=1))
        rows.append(np.concatenate(sum(([im, gap] for im in p[3:]), [])[:-1], axis=1))
    sheet = np.concatenate(sum(([r, np.ones((4, r.shape[1], 3))] for r in rows), [])[:-1], axis=0)
    mi.util.write_bitmap(args.png, mi.TensorXf(sheet.astype(np.float32)), write_async=False)
    print("wrote %s (per scene: patch layouts, then signed errors x %.0f: uniform at the default size | dark "
          "splits + refine | uniform at the smallest size)" % (os.path.relpath(args.png, ROOT), 1 / ERROR_SCALE))


if __name__ == "__main__":
    main()
