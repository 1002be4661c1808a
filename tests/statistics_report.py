"""The test suite's statistics: power, expected false failures, ratio distributions.

    python3 tests/statistics_report.py                    # breakdown of the last test run
    python3 tests/statistics_report.py --run              # run the suite first (make test's pytest)
    python3 tests/statistics_report.py --measure-ratios [NAME ...] [--blocks 24]

The suite records every statistical assertion (``tests/budget.py``) and writes them to
``reports/test_statistics.json``. This script sums their false-failure probabilities
(the expected number of failures of a correct package per full re-draw of all seeds,
which must stay below 0.01), lists the checks with the least power, and measures the
distribution of the ratio statistics over independent seed blocks (stored in
``tests/data/ratio_tests.json``, from which each ratio assertion's false-failure
probability is computed).
"""
import argparse
import fcntl
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
BUDGET_LIMIT = 0.01


def report(path):
    import budget
    with open(path) as f:
        data = json.load(f)
    records = data["records"]
    kinds = {}
    for r in records:
        k = kinds.setdefault(r["kind"], [0, 0.0, 0.0])
        k[0] += 1
        k[1] += r["alpha"]
        k[2] = max(k[2], r["alpha"])
    total = sum(k[1] for k in kinds.values())
    print("statistical assertions of the run (seed offset %d):" % data.get("seed_offset", 0))
    print("  %-8s %6s %12s %12s" % ("kind", "count", "sum alpha", "largest"))
    for name, (count, alpha, largest) in sorted(kinds.items()):
        print("  %-8s %6d %12.3g %12.3g" % (name, count, alpha, largest))
    print("expected false failures per full re-draw of the seeds: %.4f (limit %.2f): %s"
          % (total, BUDGET_LIMIT, "OK" if total < BUDGET_LIMIT else "TOO HIGH"))
    harness = sorted((r for r in records if r["kind"] == "harness" and r["passed"]),
                     key=lambda r: -r["relative_tolerance"])
    if harness:
        print("\nleast powerful passing harness checks (relative tolerance; rule <= %.3g %%):"
              % (100 * budget.POWER_LIMIT))
        for r in harness[:15]:
            limit, reason = budget.limit_for(r["test"])
            print("  %6.3f %%  %s%s" % (100 * r["relative_tolerance"], r["test"],
                                        "  [exception: %.3g %%]" % (100 * limit) if reason else ""))
    ratios = [r for r in records if r["kind"] == "ratio"]
    if ratios:
        print("\nratio assertions (value, predictive false-failure probability):")
        for r in ratios:
            print("  %-40s %8.4g  %.2g" % (r["name"], r["value"], r["alpha"]))
    return 0 if total < BUDGET_LIMIT else 1


def measure_ratios(names, blocks, first):
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import mi_plugins  # noqa: F401
    import importlib
    import budget
    import conftest  # noqa: F401  (the suite's set-up: observers, seed offset)
    for module in sorted(os.listdir(HERE)):
        if module.startswith("test_") and module.endswith(".py"):
            importlib.import_module(module[:-3])
    unknown = [n for n in names if n not in budget.RATIO_STATISTICS]
    if unknown:
        raise SystemExit("unknown ratio statistics: %s; known: %s" % (unknown, sorted(budget.RATIO_STATISTICS)))
    for name in names or sorted(budget.RATIO_STATISTICS):
        t0 = time.perf_counter()
        values = [float(budget.RATIO_STATISTICS[name](block)) for block in range(first, first + blocks)]
        _store(budget.RATIO_DATA, name, values)
        import numpy as np
        logs = np.log(values)
        print("%-40s blocks %d..%d: min %.4g, median %.4g, max %.4g, log-sd %.3g (%.0f s)"
              % (name, first, first + blocks - 1, min(values), float(np.median(values)), max(values),
                 logs.std(ddof=1), time.perf_counter() - t0), flush=True)


def _store(path, name, values):
    with open(path + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        data = {}
        if os.path.exists(path):
            with open(path) as f:
                data = json.load(f)
        data[name] = {"values": values, "measured": time.strftime("%Y-%m-%d")}
        with open(path, "w") as f:
            json.dump(data, f, indent=1, sort_keys=True)
            f.write("\n")


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", action="store_true", help="run the test suite first")
    p.add_argument("--log", default=None, help="statistics file (default: reports/test_statistics.json)")
    p.add_argument("--measure-ratios", nargs="*", metavar="NAME", default=None,
                   help="measure these ratio statistics (all when no name is given)")
    p.add_argument("--blocks", type=int, default=24, help="seed blocks per ratio statistic")
    p.add_argument("--first-block", type=int, default=1)
    args = p.parse_args()
    if args.measure_ratios is not None:
        measure_ratios(args.measure_ratios, args.blocks, args.first_block)
        return 0
    import budget
    path = args.log or budget.LOG
    if args.run:
        subprocess.call([sys.executable, "-m", "pytest", "-q"], cwd=os.path.dirname(HERE))
    if not os.path.exists(path):
        raise SystemExit("%s does not exist: run the test suite (make test) or pass --run" % path)
    return report(path)


if __name__ == "__main__":
    sys.exit(main())
