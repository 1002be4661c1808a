"""The smooth display's error on an interior of the benchmark family, split into bias and
noise (docs/solutions.md, "Open cases"): four seeds of each setting against a `path`
reference whose own noise is taken out (its two halves), split as the interior benchmark
splits them (`interior_report.split`); RMSE = sqrt(bias^2 + noise^2). The bias is given
with its range at +-2 standard errors of its square, on the whole image and away from
emitters (two seeds left the bias near a lamp's edge undecided: its terms there are
heavy-tailed). Also the 8 x 8-pixel blocks of the seeds' mean off by more than 1 %, and
the image mean's ratio.

Run from the repository root (the reference is cached under the temp dir):

    python3 benchmarks/display_bias.py [--scene room] [--resolution 128] [--ref-spp 4096]
"""
import argparse
import os
import sys
import time

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401  (registers the plugins)
from mi_plugins.patches.tessellation import default_patch_size  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import interior_ladder as ladder  # noqa: E402
import interior_report as report  # noqa: E402
import interiors  # noqa: E402

#: (label, integrator dict, spp): the settings of the table
SETTINGS = [
    ("smooth, 100 k paths, 32 spp", {"type": "qmc_lighttrace", "display": "smooth", "samples": 100000}, 32),
    ("smooth, 400 k, 128 spp", {"type": "qmc_lighttrace", "display": "smooth", "samples": 400000}, 128),
    ("smooth, 1.6 M, 512 spp", {"type": "qmc_lighttrace", "display": "smooth", "samples": 1600000}, 512),
    ("smooth, 1.6 M, 512 spp, reading every patch, 4 gather samples (the former defaults)",
     {"type": "qmc_lighttrace", "display": "smooth", "samples": 1600000, "crowd_reach": 0.0, "gather_samples": 4}, 512),
    ("gather, 1.6 M, 128 spp", {"type": "qmc_lighttrace", "samples": 1600000}, 128),
    ("smooth, half the patch size, 1.6 M, 512 spp", {"type": "qmc_lighttrace", "display": "smooth",
                                                    "samples": 1600000, "patch_size": "half"}, 512),
]


def blocks(image, size=8):
    h, w = image.shape[0] // size * size, image.shape[1] // size * size
    return image[:h, :w].reshape(h // size, size, w // size, size, -1).mean(axis=(1, 3, 4))


def seed_renders(d, params, spp, seeds):
    """(images, seconds): one render of ``params`` (``patch_size`` 'half': half the scene's
    default) at ``spp`` per seed 1 .. ``seeds``, each on the scene ``d`` loaded anew, timed
    from the loaded scene to the image."""
    images, seconds = [], []
    for seed in range(1, seeds + 1):
        scene = mi.load_dict(d)
        settings = dict(params)
        if settings.get("patch_size") == "half":
            settings["patch_size"] = 0.5 * default_patch_size(scene)
        integrator = mi.load_dict(settings)
        t0 = time.perf_counter()
        images.append(np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed), dtype=np.float64))
        seconds.append(time.perf_counter() - t0)
    return images, seconds


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="room", choices=interiors.SCENES)
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--ref-spp", type=int, default=4096)
    p.add_argument("--seeds", type=int, default=4)
    args = p.parse_args()
    ref, ref_var, keep = ladder.rendered_reference(args, args.scene)
    d = interiors.scene_dict(args.scene, args.resolution)
    pct = lambda value: 100 * value / ref.mean()
    print("| `qmc_lighttrace` | seconds | RMSE | bias (range) | away from emitters: bias (range) | noise "
          "| 8 x 8 blocks off by > 1 % (worst) | image mean |")
    print("|---|---|---|---|---|---|---|---|")
    for label, params, spp in SETTINGS:
        images, seconds = seed_renders(d, params, spp, args.seeds)
        parts = report.split(images, ref, ref_var, keep)
        rel = blocks(np.mean(images, axis=0)) / blocks(ref) - 1
        span = lambda suffix: "%.2f %% (%.2f-%.2f)" % ((pct(parts["bias" + suffix]),)
                                                        + tuple(pct(v) for v in report.bias_range(parts, suffix)))
        print("| %s | %.1f | %.2f %% | %s | %s | %.2f %% | %d of %d (%+.1f %%) | %.4f |" % (
            label, np.median(seconds), pct(np.hypot(parts["bias"], parts["noise"])), span(""), span("_x"),
            pct(parts["noise"]), int((np.abs(rel) > 0.01).sum()), rel.size, 100 * rel.flat[np.argmax(np.abs(rel))],
            parts["mean_rel"]), flush=True)


if __name__ == "__main__":
    main()
