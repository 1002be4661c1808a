"""Mitsuba 3.9.1 / Dr.Jit 1.5.0: every live scene in the process slows down every render (each call traces all live instances)

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend), 2 cores.

Scenes: Mitsuba's `cornell_box()` at 16 x 16 px, 4 spp, `path`. "Leaked" scenes are
further Cornell boxes that are still referenced (as happens with a failed render's
exception, a reference cycle, a cache or a list of results); they are never rendered
again.

Expected: the cost of rendering a scene does not depend on other, unrelated scenes that
happen to be alive in the process.

Measured:

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    A. the same scene re-rendered (median of 5 renders after a warm-up), with N live Cornell boxes:
       N =  0: 0.0154 s per render
       N =  5: 0.0353 s per render
       N = 15: 0.0732 s per render
       N = 30: 0.1668 s per render
    B. 16 new scenes rendered one after another (seconds per render), fresh kernel cache:
       release: 0.58 0.03 0.02 0.02 0.01 0.00 0.02 0.02 0.02 0.02 0.02 0.03 0.01 0.02 0.02 0.03   total 0.9 s
       keep: 0.71 0.44 0.38 0.43 0.51 0.51 0.52 0.47 0.52 0.62 0.65 0.62 0.66 0.64 0.66 0.63   total 9.0 s
    (15.5 s)

A. Re-rendering the same scene (its kernels already compiled) costs about 5 ms more per
   live Cornell box: tracing every live instance's methods in every virtual call, each
   render, is pure overhead (0.015 s alone, 0.073 s with 15 live boxes, 0.17 s with 30;
   the factor grows with the plugins' tracing cost: Python plugins trace much slower).
B. Rendering a sequence of new scenes, as a test suite does: when each scene is released
   after its render the kernels are reused (the plugins' parameters are opaque), 16
   renders take 0.9 s; when each is kept alive, every render traces a larger set of
   instances and compiles a new, larger kernel (about 0.5 s each): 9.0 s, 10x slower.
   (Part B runs in child interpreters with an empty kernel cache, as a first run on a
   fresh machine; Dr.Jit's disk cache hides the compile part on a re-run.)

Cause: as in failed_render_poisons_next.py: `ad_call_symbolic` (drjit, src/extra/call.cpp)
traces the method of every instance registered in the call's domain
(`jit_registry_ptr(backend, domain, i + 1)` for every id up to the registry's bound), and
Mitsuba registers every plugin instance in its base class's domain, so each BSDF,
emitter, shape or texture call of a render is recorded for all live scenes' instances and
their code becomes part of the kernel (and of its hash, hence the recompilations).

Suggested fix: trace only the instances reachable from the rendered scene (a per-scene
registry domain, or an explicit instance set passed to the call). Users: release scenes
you no longer need and run `gc.collect()` after failed renders.

Run: `python docs/findings/live_scenes_slow_renders.py` (about 20 s on 2 cores).
"""
import os
import subprocess
import sys
import tempfile
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")


def cornell(i=0):
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = 16
    d["sensor"]["sampler"]["sample_count"] = 4
    d["white"]["reflectance"]["value"] = [0.885809 * (1 - 0.001 * i)] * 3  # opaque: same kernel
    return mi.load_dict(d)


def render_time(scene, seed):
    t0 = time.perf_counter()
    dr.eval(mi.render(scene, seed=seed))
    dr.sync_thread()
    return time.perf_counter() - t0


def sequence(keep, n=16):
    """Seconds per render of ``n`` new scenes, each released or kept after its render."""
    kept, times = [], []
    for i in range(n):
        scene = cornell(i)
        times.append(render_time(scene, i))
        if keep:
            kept.append(scene)
        del scene
    return times


def main():
    if len(sys.argv) == 2:  # child interpreter of part B
        times = sequence(sys.argv[1] == "keep")
        print("%s: %s   total %.1f s" % (sys.argv[1], " ".join("%.2f" % t for t in times), sum(times)))
        return
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    scene = cornell()
    leaked = []
    print("A. the same scene re-rendered (median of 5 renders after a warm-up), with N live Cornell boxes:")
    for n in (0, 5, 15, 30):
        while len(leaked) < n:
            leaked.append(cornell(len(leaked) + 1))
        render_time(scene, 0)  # warm-up: compiles the kernel for this set of live instances
        print("   N = %2d: %.4f s per render" % (n, np.median([render_time(scene, s) for s in range(1, 6)])))
    del leaked
    print("B. 16 new scenes rendered one after another (seconds per render), fresh kernel cache:")
    for mode in ("release", "keep"):
        with tempfile.TemporaryDirectory() as home:  # Dr.Jit keeps its kernel cache in $HOME/.drjit
            out = subprocess.run([sys.executable, __file__, mode], capture_output=True, text=True,
                                 env=dict(os.environ, HOME=home))
        print("   " + (out.stdout.strip() or out.stderr.strip().splitlines()[-1]))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
