"""How much noise does simulated emission (`simulated_area`) add over exact emission?

The paper (section 4) reports that simulating the light sources with a single random
direction (M = 1) hardly adds noise. This script renders the Sierpinski scene of the
paper (diffuse albedo 0.47) with exact emission and with `simulated_area` for each
estimator and M, at equal spp, with Mitsuba's `path` and `ptracer`, and prints the
RMSE against the exact value (L = 1) and its ratio to the exact-emission RMSE. A
Phong (n = 10) scene with simulated emission is included for reference.

    python3 benchmarks/simulated_emission_noise.py [--spp 16] [--runs 4] [--resolution 32]
"""
import argparse
import time

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

from mi_plugins.verify import analytic  # noqa: E402
from mi_plugins.verify.analytic import constant_radiance as cr  # noqa: E402
from mi_plugins.verify.analytic.harness import render_runs  # noqa: E402


def rmse(case, integrator, spp, runs):
    t0 = time.perf_counter()
    images = render_runs(case.scene(integrator), spp, runs, seed=1)
    seconds = time.perf_counter() - t0
    return float(np.sqrt(np.mean((images - case.expected()[None]) ** 2))), seconds


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--runs", type=int, default=4)
    p.add_argument("--resolution", type=int, default=32)
    args = p.parse_args()
    diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": cr.PAPER_ALBEDO}}
    rows = [("exact emission", cr.sierpinski_diffuse_exact(resolution=args.resolution))]
    for estimator in ("uniform", "cosine", "bsdf"):
        for m in (1, 4):
            rows.append(("simulated %-7s M=%d" % (estimator, m), analytic.constant_radiance_brdf(
                diffuse, 1.0, "sierpinski", samples=m, estimator=estimator, resolution=args.resolution)))
    rows.append(("phong n=10, uniform M=1", cr.sierpinski_phong_simulated(resolution=args.resolution)))
    print("Sierpinski scene, diffuse albedo 0.47, %d spp x %d runs, %d x %d px\n"
          % (args.spp, args.runs, args.resolution, args.resolution))
    print("%-26s %-8s %10s %14s %9s" % ("emission", "integ.", "RMSE", "RMSE / exact", "seconds"))
    for integrator in ("path", "ptracer"):
        base = None
        for label, case in rows:
            err, sec = rmse(case, integrator, args.spp, args.runs)
            base = err if base is None else base
            print("%-26s %-8s %10.5f %14.3f %9.2f" % (label, integrator, err, err / base, sec))
        print()


if __name__ == "__main__":
    main()
