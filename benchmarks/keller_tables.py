"""Reproduce the empty-cube rows of Tables 1-3 of Keller's report with `qmc_lighttrace`.

Cube: 12 triangles, rho = 1/2, L0 = 1/4, exact radiance 1/2, M = 29 (sequence_depth). For
N = 10^3, 10^4, 10^5 particle paths it prints

    Delta_a(N)  = sqrt( sum_k (L_k - 1/2)^2 / K )                       (Table 2)
    Delta_aw(N) = sqrt( sum_k (L_k - 1/2)^2 |A_k| / (K sum_k |A_k|) )   (Table 3)

for drand48 (lcg), PCG32 (independent), Halton, Faure and Sobol, unscrambled and
scrambled (random sequences and scrambled ones: mean over --seeds seeds), next to the
report's numbers, and Table 1: the paths needed by the adaptive termination for
epsilon = 1e-3, 3.3e-4, 1e-4 (Delta N = 1000, T = 2). Saves a PNG plot.

    python3 benchmarks/keller_tables.py [--seeds 4] [--plot keller_tables.png] [--quick]
"""
import argparse
import time

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

from mi_plugins.verify import analytic  # noqa: E402

REPORT_TABLE2 = {"lcg": (0.0647699, 0.0138841, 0.00416856), "halton": (0.0459244, 0.015322, 0.00347108),
                 "faure": (0.0375936, 0.0101492, 0.00388516), "sobol": (0.0458288, 0.0154578, 0.0139228)}
REPORT_TABLE3 = {"lcg": (0.00589147, 0.00171686, 0.000478878), "halton": (0.00514532, 0.00147316, 0.000402798),
                 "faure": (0.00398542, 0.00128062, 0.000395118), "sobol": (0.00500996, 0.00184561, 0.00152823)}
REPORT_TABLE1 = {"lcg": (42000, 100000, 330000), "halton": (33000, 92000, 266000),
                 "faure": (32000, 99000, 276000), "sobol": (30000, 95000, 310000)}
CONFIGS = [("lcg", False), ("independent", False), ("halton", False), ("halton", True), ("faure", False),
           ("faure", True), ("sobol", False), ("sobol", True)]
NS = (1000, 10000, 100000)
EPSILONS = (1e-3, 3.3e-4, 1e-4)


def cube_integrator(sequence, scramble, **kw):
    case = analytic.keller_cube(resolution=4)
    d = {"type": "qmc_lighttrace", "sequence": sequence, "scramble": scramble, "sequence_depth": 29}
    d.update(kw)
    scene = case.scene(d)
    return scene, scene.integrator()


def deviations(radiance, areas):
    d2 = (radiance[:, 0] - 0.5) ** 2
    k = len(areas)
    return np.sqrt(d2.sum() / k), np.sqrt((d2 * areas).sum() / (k * areas.sum()))


def randomised(sequence, scramble):
    return sequence in ("lcg", "independent") or scramble


def table23(seeds):
    rows = {}
    for sequence, scramble in CONFIGS:
        runs = range(seeds) if randomised(sequence, scramble) else [0]
        values = np.zeros((len(runs), len(NS), 2))
        for r, seed in enumerate(runs):
            for j, n in enumerate(NS):
                scene, integrator = cube_integrator(sequence, scramble, samples=n)
                radiance, areas = integrator.preprocess(scene, seed=seed)
                values[r, j] = deviations(radiance, areas)
        rows[(sequence, scramble)] = values.mean(axis=0)
    return rows


def table1():
    rows = {}
    for sequence, scramble in CONFIGS:
        needed = []
        for eps in EPSILONS:
            scene, integrator = cube_integrator(sequence, scramble, epsilon=eps, batch=1000, patience=2,
                                                max_samples=2000000)
            integrator.preprocess(scene, seed=0)
            needed.append(integrator.paths_used)
        rows[(sequence, scramble)] = needed
    return rows


def label(sequence, scramble):
    return sequence + (" (scrambled)" if scramble and sequence not in ("lcg", "independent") else "")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--plot", default="keller_tables.png")
    args = p.parse_args()
    t0 = time.perf_counter()
    rows = table23(args.seeds)
    for t, name, report in ((0, "Table 2: Delta_a(N)", REPORT_TABLE2), (1, "Table 3: Delta_aw(N)", REPORT_TABLE3)):
        print("\n%s, empty cube (ours | report)" % name)
        print("%-22s" % "sequence" + "".join("%24s" % ("N = %d" % n) for n in NS))
        for (sequence, scramble), values in rows.items():
            rep = report.get(sequence) if not scramble else None
            cells = "".join("%12.3g | %-9s" % (values[j, t], ("%.3g" % rep[j]) if rep else "-") for j in range(3))
            print("%-22s%s" % (label(sequence, scramble), cells))
    print("\nTable 1: paths needed for termination (Delta N = 1000, T = 2), empty cube (ours | report)")
    print("%-22s" % "sequence" + "".join("%22s" % ("eps = %.2g" % e) for e in EPSILONS))
    t1 = table1()
    for (sequence, scramble), needed in t1.items():
        rep = REPORT_TABLE1.get(sequence) if not scramble else None
        print("%-22s" % label(sequence, scramble) + "".join(
            "%11d | %-8s" % (needed[j], rep[j] if rep else "-") for j in range(3)))
    print("\n(%.1f s)" % (time.perf_counter() - t0))
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot")
        return
    fig, ax = plt.subplots(figsize=(6, 4))
    for (sequence, scramble), values in rows.items():
        ax.loglog(NS, values[:, 0], marker="o", label=label(sequence, scramble))
    for sequence, rep in REPORT_TABLE2.items():
        ax.loglog(NS, rep, linestyle=":", color="gray")
    ax.set_xlabel("paths N")
    ax.set_ylabel("Delta_a(N)")
    ax.set_title("Keller's empty cube (dotted: report)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.plot, dpi=120)
    print("saved " + args.plot)


if __name__ == "__main__":
    main()
