"""The demo's budgets (docs/solutions.md, "The demo: budgets and a walkthrough"): how the
smooth display's error away from the lamp falls with the solve's size and the camera
samples on the demo's Cornell box, and the solve's share of a row's seconds end to end.

1. **Table**: `qmc_lighttrace` and `ray_bundle` (smooth) at three solve sizes x four
   camera-sample counts, and `path` at four, 2 seeds each: RMSE away from the lamp (per cent
   of the image mean, the reference's noise taken out) and CPU seconds.
2. **Shares**: `timesplit.solve_and_display` at several shares of a row's seconds against
   `path` at equal time, 2 seeds.

Run from the repository root (the reference is the demo's, cached under the temp dir):

    python3 benchmarks/demo_budgets.py [--resolution 128] [--seconds 5] [--shares 0.6,0.8,0.95] [--parts table,shares]
"""
import argparse
import time

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402
from mi_plugins.app import demo, cached_references, timesplit  # noqa: E402

SIZES = {"qmc_lighttrace": (400000, 1600000, 6400000), "ray_bundle": (16, 32, 64)}
SPPS = (4, 16, 64, 256)
PATH_SPPS = (16, 64, 256, 1024)


def cpu_timed(fn):
    c0 = time.process_time()
    out = fn()
    return out, time.process_time() - c0


def table(d, ref, say):
    say("| method | solve | CPU s | " + " | ".join("%d spp" % s for s in SPPS) + " |")
    say("|---|---|---|" + "---|" * len(SPPS))
    for kind, sizes in SIZES.items():
        name = timesplit.SIZE[kind][0]
        mi.render(mi.load_dict(d), integrator=mi.load_dict({"type": kind, "display": "smooth", name: sizes[0]}), spp=1)
        for size in sizes:
            errs, cpu = np.zeros(len(SPPS)), []
            for seed in (1, 2):
                scene, integ = mi.load_dict(d), mi.load_dict({"type": kind, "display": "smooth", name: size})
                cpu.append(cpu_timed(lambda: mi_plugins.solve(scene, integ, seed=seed))[1])
                for k, spp in enumerate(SPPS):
                    image = np.array(mi.render(scene, integrator=integ, spp=spp, seed=seed))
                    errs[k] += ref.errors(image)[1] / 2
            say("| %s | %s %d | %.2f | %s |" % (kind, name, size, np.mean(cpu),
                                                 " | ".join("%.2f" % (100 * e) for e in errs)))
    integ = mi.load_dict({"type": "path"})
    mi.render(mi.load_dict(d), integrator=integ, spp=1)
    scene = mi.load_dict(d)
    for spp in PATH_SPPS:
        runs = [cpu_timed(lambda: np.array(mi.render(scene, integrator=integ, spp=spp, seed=seed))) for seed in (1, 2)]
        say("| path | %d spp | %.2f | %.2f |" % (spp, np.mean([c for _, c in runs]),
                                               100 * np.mean([ref.errors(image)[1] for image, _ in runs])))


def shares(d, ref, seconds, share_list, say):
    rates = {kind: timesplit.SolveRate.measure(lambda: mi.load_dict(d), {"type": kind, "display": "smooth"}, seed=9)
             for kind in SIZES}
    mi.render(mi.load_dict(d), integrator=mi.load_dict({"type": "path"}), spp=1)
    say("| seed | method | share | solve | spp | seconds | RMSE away from the lamp % |")
    say("|---|---|---|---|---|---|---|")
    for seed in (1, 2):
        image, _, spent = demo.equal_time(mi.load_dict(d), {"type": "path"}, demo.SPP["path"], seconds, seed=seed)
        say("| %d | path | | | | %.1f | %.2f |" % (seed, spent, 100 * ref.errors(image)[1]))
        for share in share_list:
            for kind, rate in rates.items():
                image, info = timesplit.solve_and_display(mi.load_dict(d), rate, seconds, share=share, seed=seed)
                say("| %d | %s | %.2f | %s %d, %.1f s | %d | %.1f | %.2f |" % (
                    seed, kind, share, rate.name, info["size"], info["solve_seconds"], info["spp"], info["seconds"],
                    100 * ref.errors(image)[1]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--seconds", type=float, default=5.0, help="a row's seconds (--parts shares)")
    ap.add_argument("--shares", default="0.6,0.8,0.95")
    ap.add_argument("--parts", default="table,shares")
    args = ap.parse_args()
    d = demo.cornell(args.resolution)
    ref = cached_references.path_references(d, demo.REFERENCE_SPP, tag="demo", out=print)[0]

    def say(text):
        print(text, flush=True)
    if "table" in args.parts:
        table(d, ref, say)
    if "shares" in args.parts:
        shares(d, ref, args.seconds, [float(s) for s in args.shares.split(",")], say)


if __name__ == "__main__":
    main()
