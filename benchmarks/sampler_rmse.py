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
"""
import argparse
import os
import sys
import time

import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")
from mi_plugins import analytic  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import real_scene_meshes as rsm  # noqa: E402

MITSUBA = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
PACKAGE = ("sobol", "halton", "faure", "padded_sobol", "zsobol", "lattice")
CASES = ("diffuse_sphere_depth2", "diffuse_sphere", "bekaert_box", "cornell_box")
#: orthogonal's own counts for the requested ones
ORTHOGONAL = {16: 25, 64: 121}
CORNELL_RES, CORNELL_REF_SPP = 32, 1 << 16


def analytic_case(name, resolution):
    if name.startswith("diffuse_sphere"):
        integrator = {"type": "path", "max_depth": 2} if name.endswith("depth2") else {"type": "path"}
        return analytic.diffuse_sphere(resolution=resolution), integrator
    return analytic.bekaert("box", resolution=resolution), {"type": "path"}


def cornell(sampler, spp, runs, ref):
    d, _ = rsm.scene_dict("cornell", CORNELL_RES)
    d["sensor"]["sampler"] = {"type": sampler, "sample_count": spp}
    scene, integrator = mi.load_dict(d), mi.load_dict({"type": "path"})
    image, ref_var = ref
    errors, means = [], []
    for j in range(runs):
        img = np.array(mi.render(scene, integrator=integrator, spp=spp, seed=j), dtype=np.float64)
        errors.append(np.mean((img - image) ** 2 - ref_var))
        means.append(img.mean())
    z = (np.mean(means) - image.mean()) / (np.std(means, ddof=1) / np.sqrt(runs))
    return float(np.sqrt(max(np.mean(errors), 0.0))), abs(z) <= 4.5


def measure(case_name, sampler, spp, runs, resolution, ref):
    """(RMSE, unbiased at this budget) of `path` with ``sampler`` at ``spp``."""
    if case_name == "cornell_box":
        return cornell(sampler, spp, runs, ref)
    case, integrator = analytic_case(case_name, resolution)
    r = analytic.check(case, integrator, spp=spp, runs=runs, sampler={"type": sampler})
    return r.rmse, r.passed


def rounded(sampler, spp):
    """The count Mitsuba's sampler actually uses for ``spp``."""
    return int(mi.load_dict({"type": sampler, "sample_count": spp}).sample_count())


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--spp", default="4,16,64")
    p.add_argument("--runs", type=int, default=8)
    p.add_argument("--resolution", type=int, default=16)
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--markdown", action="store_true", help="print the table as Markdown (for the docs)")
    args = p.parse_args()
    mi.set_log_level(mi.LogLevel.Error)       # the samplers' rounding warnings are in the table
    counts = []
    for spp in (int(s) for s in args.spp.split(",")):
        counts.append((spp, tuple(s for s in MITSUBA if spp not in ORTHOGONAL or s != "orthogonal")))
        if spp in ORTHOGONAL:
            counts.append((ORTHOGONAL[spp], ("independent", "orthogonal")))
    cases = args.cases.split(",")
    ref = rsm.reference("cornell", CORNELL_RES, CORNELL_REF_SPP) if "cornell_box" in cases else None
    samplers = MITSUBA + PACKAGE
    header = ["case", "spp"] + list(samplers) + ["best of package / best of Mitsuba"]
    rows, t0 = [], time.perf_counter()
    for case_name in cases:
        for spp, mitsuba_here in counts:
            cells, rmse = [], {}
            for s in samplers:
                if s in MITSUBA and s not in mitsuba_here:
                    cells.append("")
                    continue
                value, unbiased = measure(case_name, s, spp, args.runs, args.resolution, ref)
                rmse[s] = value
                mark = ("" if s in PACKAGE or rounded(s, spp) == spp else " (%d)" % rounded(s, spp)) \
                    + ("" if unbiased else " !")
                cells.append("%.3f%s" % (value / rmse.get("independent", value), mark))
            ours = min(rmse[s] for s in PACKAGE)
            theirs = min(rmse[s] for s in mitsuba_here if s != "independent")
            best = min(PACKAGE, key=rmse.get)
            rows.append([case_name, str(spp)] + cells + ["%.3f (%s)" % (ours / theirs, best)])
            print("  ".join(rows[-1]), flush=True) if not args.markdown else None
    print("# %.0f s, %d runs, analytic cases %d px, Cornell box %d px" % (time.perf_counter() - t0, args.runs,
                                                                         args.resolution, CORNELL_RES))
    if args.markdown:
        print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
        for row in rows:
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
