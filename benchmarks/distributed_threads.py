"""Multi-threaded Dask workers against single-threaded ones (mi_plugins.distributed) on
this machine: the render of distributed_speedup.py (the Cornell box of
real_scene_meshes.py as an XML file with its meshes, `--tasks` tasks) on 1 worker with
1 Dask thread, 1 worker with 2 Dask threads (a worker runs its tasks one at a time:
mi_plugins.distributed.serial) and 2 workers with 1 Dask thread each; Dr.Jit's threads
are the machine's cores divided among the workers. The three clusters render in turn
(so that a load that comes and goes on the machine hits them alike) after a warm-up
render each; the fastest of `--repeats`; seconds, and the image mean against the
one-thread worker's.
Run from the repository root:

    python3 benchmarks/distributed_threads.py [--resolution 128] [--tasks 16] [--repeats 2]
"""
import os
import sys
import time

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")

import mi_plugins  # noqa: E402,F401
from mi_plugins import distributed  # noqa: E402
from mi_plugins.distributed import dask_engine, serial  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from distributed_speedup import CONFIGS, arguments, scene_file  # noqa: E402

CLUSTERS = {"1 worker x 1 thread": (1, 1), "1 worker x 2 threads": (1, 2), "2 workers x 1 thread": (2, 1)}


def client_of(workers, threads):
    """A LocalCluster of ``workers`` processes of ``threads`` Dask threads each, its client."""
    from distributed import Client, LocalCluster
    if threads == 1:
        return distributed.local_cluster(workers)
    cores = max(1, (os.cpu_count() or 1) // workers)
    client = Client(LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True,
                                 dashboard_address=":0", env={"MI_PLUGINS_VARIANT": mi.variant()}))
    client.mi_plugins_threads = cores
    return client


def main():
    args = arguments(__doc__)
    clients = {label: client_of(*shape) for label, shape in CLUSTERS.items()}
    rows = []
    try:
        for client in clients.values():
            dask_engine.set_variant_on(client, mi.variant())
        for name in args.integrators.split(","):
            integrator, spp = CONFIGS[name]
            path = scene_file(name, integrator, args.resolution)
            run = lambda client, s: distributed.render(path, s, client=client, seed=1, tasks=args.tasks,
                                                       progress=False).image
            for client in clients.values():
                run(client, min(spp, args.tasks))                                       # warm-up
                client.run(serial.stats, reset=True)
            seconds, means = {label: [] for label in clients}, {}
            for _ in range(args.repeats):              # the clusters in turn: a load that comes and goes hits all
                for label, client in clients.items():
                    t0 = time.perf_counter()
                    means[label] = float(run(client, spp).mean())
                    seconds[label].append(time.perf_counter() - t0)
            row = dict({label: min(t) for label, t in seconds.items()}, integrator=name, spp=spp,
                       means={k: v / means["1 worker x 1 thread"] for k, v in means.items()},
                       stats=list(clients["1 worker x 2 threads"].run(serial.stats).values()))
            rows.append(row)
            print(row, {k: ["%.2f" % x for x in v] for k, v in seconds.items()}, flush=True)
    finally:
        for client in clients.values():
            cluster = client.cluster
            client.close()
            cluster.close()
    print("\n%d x %d px, %d tasks, fastest of %d renders, seconds:" % (args.resolution, args.resolution,
                                                                       args.tasks, args.repeats))
    print("| integrator | spp | " + " | ".join(CLUSTERS) + " | 1 x 2 / 1 x 1 |")
    print("|---|---|" + "---|" * (len(CLUSTERS) + 1))
    for r in rows:
        print("| `%s` | %d | %s | %.2f |" % (r["integrator"], r["spp"], " | ".join("%.2f" % r[k] for k in CLUSTERS),
                                            r["1 worker x 2 threads"] / r["1 worker x 1 thread"]))


if __name__ == "__main__":
    main()
