"""The smooth display's error on an interior of the benchmark family, split into bias and
noise (docs/solutions.md, "Open cases"): two seeds of each setting against a `path`
reference whose own noise is taken out (its two halves); bias^2 = mean((a - ref)(b - ref))
- the reference's noise, noise^2 = the rest of the mean squared error. Also the 8 x 8-pixel
blocks of the two seeds' mean off by more than 1 %, and the image mean's ratio.

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
import interiors  # noqa: E402

#: (label, integrator dict, spp): the settings of the table
SETTINGS = [
    ("smooth, 100 k paths, 32 spp", {"type": "qmc_lighttrace", "display": "smooth", "samples": 100000}, 32),
    ("smooth, 400 k, 128 spp", {"type": "qmc_lighttrace", "display": "smooth", "samples": 400000}, 128),
    ("smooth, 1.6 M, 512 spp", {"type": "qmc_lighttrace", "display": "smooth", "samples": 1600000}, 512),
    ("gather, 1.6 M, 128 spp", {"type": "qmc_lighttrace", "samples": 1600000}, 128),
    ("smooth, half the patch size, 1.6 M, 512 spp", {"type": "qmc_lighttrace", "display": "smooth",
                                                    "samples": 1600000, "patch_size": "half"}, 512),
]


def blocks(image, size=8):
    h, w = image.shape[0] // size * size, image.shape[1] // size * size
    return image[:h, :w].reshape(h // size, size, w // size, size, -1).mean(axis=(1, 3, 4))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="room", choices=interiors.SCENES)
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--ref-spp", type=int, default=4096)
    args = p.parse_args()
    if not os.path.exists(ladder.reference_file(args, args.scene)):
        ladder.render_reference(args, args.scene)
    ref, ref_var, _ = ladder.reference(args, args.scene)
    d = interiors.scene_dict(args.scene, args.resolution)
    mean = ref.mean()
    print("| `qmc_lighttrace` | seconds | RMSE | bias | noise | 8 x 8 blocks off by > 1 % (worst) | image mean |")
    print("|---|---|---|---|---|---|---|")
    for label, params, spp in SETTINGS:
        images, seconds = [], []
        for seed in (1, 2):
            scene = mi.load_dict(d)
            params = dict(params)
            if params.get("patch_size") == "half":
                params["patch_size"] = 0.5 * default_patch_size(scene)
            integrator = mi.load_dict(params)
            t0 = time.perf_counter()
            images.append(np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed), dtype=np.float64))
            seconds.append(time.perf_counter() - t0)
        e0, e1 = images[0] - ref, images[1] - ref
        mse = 0.5 * ((e0 ** 2).mean() + (e1 ** 2).mean()) - ref_var.mean()
        bias2 = (e0 * e1).mean() - ref_var.mean()
        both = 0.5 * (images[0] + images[1])
        rel = blocks(both) / blocks(ref) - 1
        pct = lambda v: 100 * np.sqrt(max(v, 0.0)) / mean
        print("| %s | %.1f | %.2f %% | %.2f %% | %.2f %% | %d of %d (%+.1f %%) | %.4f |" % (
            label, np.median(seconds), pct(mse), pct(bias2), pct(mse - bias2), int((np.abs(rel) > 0.01).sum()),
            rel.size, 100 * rel.flat[np.argmax(np.abs(rel))], both.mean() / mean), flush=True)


if __name__ == "__main__":
    main()
