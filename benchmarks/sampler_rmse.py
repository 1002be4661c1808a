"""RMSE of Mitsuba's `path` with this package's samplers relative to `independent`.

Equal spp, several independent runs, on smooth analytic cases (exact reference):

    python3 benchmarks/sampler_rmse.py [--spp 16] [--runs 8] [--resolution 16]
"""
import argparse

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
from mi_plugins import analytic  # noqa: E402

CASES = [("diffuse_sphere, max_depth 2", lambda r: analytic.diffuse_sphere(resolution=r), {"type": "path", "max_depth": 2}),
         ("diffuse_sphere, full depth", lambda r: analytic.diffuse_sphere(resolution=r), {"type": "path"}),
         ("bekaert_box", lambda r: analytic.bekaert("box", resolution=r), {"type": "path"})]
SAMPLERS = ("independent", "sobol", "halton", "faure")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--runs", type=int, default=8)
    p.add_argument("--resolution", type=int, default=16)
    args = p.parse_args()
    print("%-30s %-12s %10s %10s %7s" % ("case", "sampler", "RMSE", "ratio", "check"))
    for name, factory, integrator in CASES:
        case = factory(args.resolution)
        base = None
        for sampler in SAMPLERS:
            r = analytic.check(case, integrator, spp=args.spp, runs=args.runs, sampler={"type": sampler})
            base = base or r.rmse
            print("%-30s %-12s %10.5f %10.3f %7s" % (name, sampler, r.rmse, r.rmse / base, r.status))


if __name__ == "__main__":
    main()
