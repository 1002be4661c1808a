"""RMSE of Mitsuba's `path` with every Mitsuba sampler and every sampler of this package,
at equal samples per pixel, in one run.

Cases: the diffuse sphere (exact; ``max_depth`` 2, i.e. one bounce, and full depth), Bekaert's box (exact) and
the measured Cornell box (against a cached `path` reference of 2^16 spp whose own noise
is subtracted). Each cell is the RMSE over ``--runs`` seeds relative to `independent` at
the same count; `orthogonal` rounds 16 to 25 and 64 to 121 samples (squares of primes),
so it has its own rows at those counts, where every other sampler is run at the same
count too (stratified, multijitter and ldsampler round those counts themselves: marked
in the table). A cell marked ``!`` failed the unbiasedness check at that budget
(|mean - exact| beyond the harness bound; the Cornell box: beyond 4.5 SE of the run
means).

    python3 benchmarks/sampler_rmse.py [--spp 4,16,64] [--runs 8] [--resolution 16] [--markdown]
        [--samplers a,b,...] [--blocks K] [--rr-depth D] [--cost]

``--blocks K`` repeats every cell over K disjoint blocks of ``--runs`` seeds and prints
the mean and standard error of the K RMSEs (differences of 1-2 % between samplers need
it: one block of 256 runs varies by about 1 %). ``--rr-depth`` sets `path`'s
``rr_depth`` (e.g. 1000: no Russian roulette), to separate the roulette's share of the
error from the rest. ``--cost`` prints instead each sampler's render time relative to
`independent` (the Cornell box at 128 x 128 px, 64 spp, `path`).
"""
import argparse
import os
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")
from mi_plugins.verify import analytic  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import real_scene_meshes as rsm  # noqa: E402

MITSUBA = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
PACKAGE = ("sobol", "halton", "faure", "padded_sobol", "zsobol", "lattice", "cmj")
CASES = ("diffuse_sphere_depth2", "diffuse_sphere", "bekaert_box", "cornell_box")
#: orthogonal's own counts for the requested ones
ORTHOGONAL = {16: 25, 64: 121}
CORNELL_RES, CORNELL_REF_SPP = 32, 1 << 16


def path_dict(rr_depth=None, **extra):
    """Mitsuba's `path` with its defaults, or with the given ``rr_depth``."""
    return dict(type="path", **extra, **({} if rr_depth is None else {"rr_depth": int(rr_depth)}))


def analytic_case(name, resolution, rr_depth=None):
    if name.startswith("diffuse_sphere"):
        extra = {"max_depth": 2} if name.endswith("depth2") else {}
        return analytic.diffuse_sphere(resolution=resolution), path_dict(rr_depth, **extra)
    return analytic.bekaert("box", resolution=resolution), path_dict(rr_depth)


def cornell_scene(sampler, spp, resolution=CORNELL_RES, rr_depth=None):
    """(scene, `path`) of the measured Cornell box with ``sampler`` at ``spp``."""
    d, _ = rsm.scene_dict("cornell", resolution)
    d["sensor"]["sampler"] = {"type": sampler, "sample_count": spp}
    return mi.load_dict(d), mi.load_dict(path_dict(rr_depth))


def cornell(sampler, spp, runs, ref, block=0, rr_depth=None):
    scene, integrator = cornell_scene(sampler, spp, rr_depth=rr_depth)
    image, ref_var = ref
    errors, means = [], []
    for j in range(block * runs, (block + 1) * runs):
        img = np.array(mi.render(scene, integrator=integrator, spp=spp, seed=j), dtype=np.float64)
        errors.append(np.mean((img - image) ** 2 - ref_var))
        means.append(img.mean())
    z = (np.mean(means) - image.mean()) / (np.std(means, ddof=1) / np.sqrt(runs))
    return float(np.sqrt(max(np.mean(errors), 0.0))), abs(z) <= 4.5


def measure(case_name, sampler, spp, runs, resolution, ref, block=0, rr_depth=None):
    """(RMSE, unbiased at this budget) of `path` with ``sampler`` at ``spp`` over block
    ``block`` of ``runs`` render seeds (blocks are disjoint; block 0 is the default run)."""
    if case_name == "cornell_box":
        return cornell(sampler, spp, runs, ref, block, rr_depth)
    case, integrator = analytic_case(case_name, resolution, rr_depth)
    r = analytic.check(case, integrator, spp=spp, runs=runs, seed=block, sampler={"type": sampler})
    return r.rmse, r.passed


def measure_blocks(blocks, case_name, sampler, spp, runs, resolution, ref, rr_depth=None):
    """(mean RMSE, its standard error or None for one block, unbiased in every block) over
    ``blocks`` disjoint blocks of ``runs`` seeds."""
    values, unbiased = [], True
    for b in range(blocks):
        value, ok = measure(case_name, sampler, spp, runs, resolution, ref, b, rr_depth)
        values.append(value)
        unbiased &= ok
    se = float(np.std(values, ddof=1) / np.sqrt(blocks)) if blocks > 1 else None
    return float(np.mean(values)), se, unbiased


def rounded(sampler, spp):
    """The count Mitsuba's sampler actually uses for ``spp``."""
    return int(mi.load_dict({"type": sampler, "sample_count": spp}).sample_count())


def render_seconds(sampler, resolution=128, spp=64, repeats=3):
    """Shortest wall time of `path` rendering the Cornell box with ``sampler`` (compiled
    kernels: one render before timing)."""
    scene, integrator = cornell_scene(sampler, spp, resolution)
    times = []
    for k in range(repeats + 1):
        t0 = time.perf_counter()
        dr.eval(mi.render(scene, integrator=integrator, spp=spp, seed=k))
        dr.sync_thread()
        times.append(time.perf_counter() - t0)
    return min(times[1:])


def print_cost(samplers):
    """Render time of every sampler relative to `independent` (Cornell box, 128 px, 64 spp)."""
    base = render_seconds("independent")
    print("| sampler | seconds | relative to independent |\n|---|---|---|")
    for s in samplers:
        t = base if s == "independent" else render_seconds(s)
        print("| %s | %.3f | %.2f |" % (s, t, t / base))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--spp", default="4,16,64")
    p.add_argument("--runs", type=int, default=8)
    p.add_argument("--resolution", type=int, default=16)
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--samplers", default=",".join(MITSUBA + PACKAGE),
                   help="the samplers to run (cells are relative to `independent` when it is among them)")
    p.add_argument("--blocks", type=int, default=1, help="disjoint blocks of --runs seeds per cell (mean +- SE)")
    p.add_argument("--rr-depth", type=int, default=None, help="`path`'s rr_depth (default: Mitsuba's)")
    p.add_argument("--markdown", action="store_true", help="print the table as Markdown (for the docs)")
    p.add_argument("--cost", action="store_true",
                   help="only the render time of each sampler relative to `independent` (Cornell box, 128 px, 64 spp)")
    args = p.parse_args()
    mi.set_log_level(mi.LogLevel.Error)       # the samplers' rounding warnings are in the table
    samplers = tuple(args.samplers.split(","))
    unknown = [s for s in samplers if s not in MITSUBA + PACKAGE]
    if unknown or args.blocks < 1:
        p.error("--samplers: unknown %s (choose from %s)" % (unknown, ", ".join(MITSUBA + PACKAGE)) if unknown
                else "--blocks=%d: must be >= 1" % args.blocks)
    if args.cost:
        return print_cost(samplers)
    counts = []
    for spp in (int(s) for s in args.spp.split(",")):
        counts.append((spp, tuple(s for s in MITSUBA if spp not in ORTHOGONAL or s != "orthogonal")))
        if spp in ORTHOGONAL and "orthogonal" in samplers:
            counts.append((ORTHOGONAL[spp], ("independent", "orthogonal")))
    cases = args.cases.split(",")
    ref = rsm.reference("cornell", CORNELL_RES, CORNELL_REF_SPP) if "cornell_box" in cases else None
    header = ["case", "spp"] + list(samplers) + ["best of package / best of Mitsuba"]
    rows, t0 = [], time.perf_counter()
    for case_name in cases:
        for spp, mitsuba_here in counts:
            cells, rmse = [], {}
            for s in samplers:
                if s in MITSUBA and s not in mitsuba_here:
                    cells.append("")
                    continue
                value, se, unbiased = measure_blocks(args.blocks, case_name, s, spp, args.runs, args.resolution,
                                                     ref, args.rr_depth)
                rmse[s] = value
                relative = "independent" in rmse              # else absolute RMSE
                unit, digits = (rmse["independent"], "%.3f") if relative else (1.0, "%.5f")
                mark = ("" if s in PACKAGE or rounded(s, spp) == spp else " (%d)" % rounded(s, spp)) \
                    + ("" if unbiased else " !")
                cells.append(digits % (value / unit) + ("" if se is None else " +- " + digits % (se / unit)) + mark)
            ours = [s for s in PACKAGE if s in rmse]
            theirs = [s for s in mitsuba_here if s != "independent" and s in rmse]
            best = min(ours, key=rmse.get) if ours else None
            rows.append([case_name, str(spp)] + cells + ["%.3f (%s)" % (rmse[best] / min(rmse[s] for s in theirs), best)
                                                         if ours and theirs else ""])
            print("  ".join(rows[-1]), flush=True) if not args.markdown else None
    print("# %.0f s, %d block(s) of %d runs, analytic cases %d px, Cornell box %d px%s"
          % (time.perf_counter() - t0, args.blocks, args.runs, args.resolution, CORNELL_RES,
             "" if args.rr_depth is None else ", rr_depth %d" % args.rr_depth))
    if args.markdown:
        print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
        for row in rows:
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
