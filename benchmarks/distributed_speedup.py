"""Speed-up of distributed rendering (mi_plugins.distributed, Dask LocalCluster) with 1
and 2 worker processes on this machine, for `path`, `qmc_lighttrace` and `ray_bundle`
(defaults) on the Cornell box of real_scene_meshes.py, written as an XML file with its
meshes next to it (shipped with the tasks).

Per integrator, the render (spp, seed) in one process (`mi.render`, 2 threads), and the
same render split into `--tasks` tasks on 1 worker with 1 Dr.Jit thread, on 1 worker
with 2 threads and on 2 workers with 1 thread each, every one after a warm-up render on
the same cluster (compiled kernels, loaded scene); and the overhead per task, with
`path`: (16 one-sample tasks on 1 worker with 2 threads - one 16-spp render in one
process) / 16.
Run from the repository root:

    python3 benchmarks/distributed_speedup.py [--resolution 128] [--tasks 16] [--repeats 2]
"""
import argparse
import os
import sys
import time

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401
from mi_plugins import distributed  # noqa: E402
from mi_plugins.base.scene_xml import write_scene  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import real_scene_meshes as rsm  # noqa: E402

#: integrator dict and spp of a render of about 5-10 s on 2 cores at 128 px
CONFIGS = {"path": ({"type": "path", "max_depth": -1}, 512),
           "qmc_lighttrace": ({"type": "qmc_lighttrace"}, 256),
           "ray_bundle": ({"type": "ray_bundle"}, 4)}


def scene_file(name, integrator, resolution):
    d, _ = rsm.scene_dict("cornell", resolution)
    path = os.path.join(HERE, ".cache", "distributed", "cornell_%s_%dpx.xml" % (name, resolution))
    write_scene(dict(d, integrator=integrator), path)
    return path


def timed(fn, repeats):
    best = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        dt = time.perf_counter() - t0
        best = dt if best is None else min(best, dt)
    return best, out


def arguments(doc):
    """The options of this benchmark and of distributed_threads.py, parsed."""
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--tasks", type=int, default=16)
    p.add_argument("--repeats", type=int, default=2, help="renders per configuration (the fastest counts)")
    p.add_argument("--integrators", default=",".join(CONFIGS))
    return p.parse_args()


def main():
    args = arguments(__doc__)
    clusters = {"1 worker x 1 thread": (1, 1), "1 worker x 2 threads": (1, 2), "2 workers x 1 thread": (2, 1)}
    rows = []
    for name in args.integrators.split(","):
        integrator, spp = CONFIGS[name]
        path = scene_file(name, integrator, args.resolution)
        scene = mi.load_file(path)
        np.array(mi.render(scene, spp=args.tasks))                               # warm-up
        single, ref = timed(lambda: np.array(mi.render(scene, spp=spp, seed=1)), args.repeats)
        tiny_single, _ = timed(lambda: np.array(mi.render(scene, spp=args.tasks)), 1)
        row = {"integrator": name, "spp": spp, "one process": single}
        for label, (workers, threads) in clusters.items():
            client = distributed.local_cluster(workers, threads=threads)
            try:
                run = lambda s, seed=1: distributed.render(path, s, client=client, seed=seed, tasks=args.tasks,
                                                          progress=False)
                run(args.tasks)                                                          # warm-up
                row[label], res = timed(lambda: run(spp).image, args.repeats)
                if label == "1 worker x 2 threads":
                    tiny, _ = timed(lambda: run(args.tasks), 1)
                    row["overhead per task"] = (tiny - tiny_single) / args.tasks
                row["mean rel " + label] = float(res.mean() / ref.mean())
            finally:
                cluster = client.cluster
                client.close()
                cluster.close()
        rows.append(row)
        print(row, flush=True)
    print("\n%d x %d px, %d tasks, fastest of %d renders, seconds:" % (args.resolution, args.resolution,
                                                                      args.tasks, args.repeats))
    print("| integrator | spp | one process | 1 worker x 1 thread | 1 worker x 2 threads | 2 workers x 1 thread "
          "| 2 workers / 1 worker (1 thread each) | overhead per task |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print("| `%s` | %d | %.2f | %.2f | %.2f | %.2f | %.2fx | %.3f s |" % (
            r["integrator"], r["spp"], r["one process"], r["1 worker x 1 thread"], r["1 worker x 2 threads"],
            r["2 workers x 1 thread"], r["1 worker x 1 thread"] / r["2 workers x 1 thread"], r["overhead per task"]))
    print("\nimage mean relative to the one-process render's: " + ", ".join(
        "%s %s" % (r["integrator"], "/".join("%.4f" % v for k, v in r.items() if k.startswith("mean rel")))
        for r in rows))


if __name__ == "__main__":
    main()
