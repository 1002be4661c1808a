"""Does the display's error keep falling? A ladder of budgets on an interior of the
benchmark family, each doubling both the particle paths and the camera samples (from
`qmc_lighttrace`'s 100 000 paths and 32 spp up to 16 times that), for the smooth display
as it is and with the residual check (`residual`), seeds against a `path` reference whose
own noise is taken out, split into bias and noise as `display_bias.py` splits them. A
display whose error is its noise falls by sqrt(2) = 1.41x per rung; a bias floor shows as
a ratio falling toward 1.

    python3 benchmarks/display_convergence.py [--scene room] [--resolution 64] [--rungs 5] [--residual 0.25]
"""
import argparse
import os
import sys

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401  (registers the plugins)

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import display_bias  # noqa: E402
import interior_ladder as ladder  # noqa: E402
import interior_report as report  # noqa: E402
import interiors  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="room", choices=interiors.SCENES)
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--ref-spp", type=int, default=4096)
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--rungs", type=int, default=5)
    p.add_argument("--residual", type=float, default=0.25)
    p.add_argument("--integrator", default="qmc_lighttrace", choices=("qmc_lighttrace", "ray_bundle"))
    args = p.parse_args()
    ref, ref_var, keep = ladder.rendered_reference(args, args.scene)
    d = interiors.scene_dict(args.scene, args.resolution)
    pct = lambda value: 100 * value / ref.mean()
    budget = "samples" if args.integrator == "qmc_lighttrace" else "iterations"
    start = 100000 if args.integrator == "qmc_lighttrace" else 16
    print("%s, %s, %d px, %d seeds; %% of the image mean" % (args.scene, args.integrator, args.resolution,
                                                             args.seeds))
    print("| display | %s | spp | seconds | RMSE | bias (range) | noise | RMSE fell by |" % budget)
    print("|---|---|---|---|---|---|---|---|")
    for label, extra in (("smooth", {}), ("smooth, residual %g" % args.residual, {"residual": args.residual})):
        last = None
        for k in range(args.rungs):
            settings = dict({"type": args.integrator, "display": "smooth", budget: start << k}, **extra)
            spp = 32 << k
            images, seconds = display_bias.seed_renders(d, settings, spp, args.seeds)
            parts = report.split(images, ref, ref_var, keep)
            rmse = np.hypot(parts["bias"], parts["noise"])
            lo, hi = report.bias_range(parts)
            print("| %s | %d | %d | %.1f | %.2f %% | %.2f %% (%.2f-%.2f) | %.2f %% | %s |" % (
                label, start << k, spp, np.median(seconds), pct(rmse), pct(parts["bias"]), pct(lo), pct(hi),
                pct(parts["noise"]), "%.2fx" % (last / rmse) if last else "-"), flush=True)
            last = rmse


if __name__ == "__main__":
    main()
