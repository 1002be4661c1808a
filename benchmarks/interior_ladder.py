"""One method's ladder on one interior scene, and the scene's reference (the child
processes of `interior_bench.py`, which describes the protocol).

A timed render loads the scene anew (:class:`Fresh`) and runs from the loaded scene to
the image in numpy; Dr.Jit's kernel history gives the compilation inside it. The budget
ladder (:func:`next_budget`) doubles the spp until a render takes the largest equal time.
"""
import gc
import hashlib
import os
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import interior_geometry as ig
import interior_report as report
import interiors

PACKAGE = {"qmc_gather": {"type": "qmc_lighttrace"}, "qmc_smooth": {"type": "qmc_lighttrace", "display": "smooth"},
           "bundle_gather": {"type": "ray_bundle"}, "bundle_smooth": {"type": "ray_bundle", "display": "smooth"}}
#: the package's methods again with the scene's sampler a stratifying one ('_ld': ldsampler,
#: '_orth': orthogonal, `path`'s best on two of the three rooms): the film positions and the
#: display's light, BSDF and gather numbers then come from it (mi_plugins/render/pass_numbers.py)
STRATIFIED = {"_ld": "ldsampler", "_orth": "orthogonal"}
PACKAGE.update({name + suffix: config for name, config in list(PACKAGE.items()) for suffix in STRATIFIED})
METHODS = report.PATHS + tuple(PACKAGE)
LANES = 1 << 21          # path: samples per pass at most this many per image (memory)


def sampler_of(method):
    if method.startswith("path_"):
        return method[5:]
    return next((sampler for suffix, sampler in STRATIFIED.items() if method.endswith(suffix)), "independent")


def spp_of(method, budget):
    """The spp a budget renders: the sampler's own rounding (stratified, orthogonal, ldsampler)."""
    if sampler_of(method) == "independent":
        return int(budget)
    level = mi.log_level()
    mi.set_log_level(mi.LogLevel.Error)
    try:
        return int(mi.load_dict({"type": sampler_of(method), "sample_count": int(budget)}).sample_count())
    finally:
        mi.set_log_level(level)


def integrator_of(method, spp, pixels):
    if method in PACKAGE:
        return dict(PACKAGE[method])
    per_pass = max(d for d in range(1, min(spp, max(1, LANES // pixels)) + 1) if spp % d == 0)
    return {"type": "path", "max_depth": -1, "samples_per_pass": per_pass}


# ---------------------------------------------------------------------------- the reference
def reference_file(args, sname):
    key = hashlib.sha1(repr((interiors.scene_key(sname, args.resolution), args.ref_spp, mi.__version__)).encode())
    return os.path.join(ig.cache_dir(), "reference-%s-%dpx-%dspp-%s.npz" % (sname, args.resolution, args.ref_spp,
                                                                           key.hexdigest()[:12]))


def render_reference(args, sname):
    """`path` at --ref-spp (independent sampler) in chunks, kept as two independent halves,
    and 256 spp of emission only (max_depth 1)."""
    t0 = time.perf_counter()
    d = interiors.scene_dict(sname, args.resolution)
    scene, pixels = mi.load_dict(d), d["sensor"]["film"]["width"] * d["sensor"]["film"]["height"]
    chunk = max(1, min(args.ref_spp // 2, (1 << 23) // pixels))
    n = max(2, 2 * (args.ref_spp // (2 * chunk)))
    halves = [0.0, 0.0]
    for c in range(n):
        integ = mi.load_dict(integrator_of("path_independent", chunk, pixels))
        halves[c % 2] = halves[c % 2] + np.array(mi.render(scene, integrator=integ, spp=chunk, seed=10 ** 6 + c),
                                                 dtype=np.float64) / (n // 2)
        print("  reference %s: %d of %d chunks of %d spp, %.0f s" % (sname, c + 1, n, chunk, time.perf_counter() - t0),
              file=sys.stderr, flush=True)
    emission = np.array(mi.render(scene, integrator=mi.load_dict({"type": "path", "max_depth": 1}), spp=256,
                                  seed=7), dtype=np.float64)
    path = reference_file(args, sname)
    np.savez(path + ".tmp.npz", halves=np.stack(halves), emission=emission)
    os.replace(path + ".tmp.npz", path)
    return dict(seconds=time.perf_counter() - t0, spp=n * chunk)


def rendered_reference(args, sname):
    """:func:`reference`, rendered first where it is not cached yet."""
    if not os.path.exists(reference_file(args, sname)):
        render_reference(args, sname)
    return reference(args, sname)


def reference(args, sname):
    """(image, per-pixel variance of its noise (per channel), mask of the pixels away from emitters)."""
    with np.load(reference_file(args, sname)) as f:
        halves, emission = f["halves"], f["emission"]
    seen = np.pad(emission.max(axis=-1) > 0, 1)
    h, w = emission.shape[:2]
    keep = ~np.any([seen[i:i + h, j:j + w] for i in range(3) for j in range(3)], axis=0)
    return halves.mean(axis=0), (halves[0] - halves[1]) ** 2 / 4.0, keep


# ---------------------------------------------------------------------------- one child: a method's ladder
class Fresh:
    """Loads the scene anew for every render; the last scene stays alive until the next
    one is loaded (as ``scene = mi.load_dict(d)`` in a user's loop), so that no cache
    keyed by an object's id can meet a new scene at an old address."""

    def __init__(self, d):
        self.d, self.scene, self.table = d, None, None

    def load(self):
        t0 = time.perf_counter()
        self.scene = mi.load_dict(self.d)
        seconds = time.perf_counter() - t0
        gc.collect()                     # the previous scene's cycles, outside the timed part
        return seconds

    def check_fresh(self, method):
        """The package built a new patch table for this scene (not one of an earlier scene)."""
        if method not in PACKAGE:
            return
        from mi_plugins.patches import build
        last = getattr(build, "_LAST", None)
        if last is None:             # (a module without this cache: nothing to check)
            return
        if not last or last[0][0][0] != id(self.scene) or last[0][1] is self.table:
            raise RuntimeError("%s: the render did not build its own patch table" % method)
        self.table = last[0][1]


def compile_seconds():
    """Seconds of kernel compilation since Dr.Jit's kernel history was last read (which
    clears it; ``JitFlag.KernelHistory`` on): the cache misses. Kernels with a virtual
    call (Mitsuba's own ``path`` as the package's) are compiled anew for every scene
    object, whose plugins' instance ids they hold."""
    return sum(k.get("backend_time", 0.0) for k in dr.kernel_history() if not k.get("cache_hit", 1)) / 1e3


def timed(fresh, method, spp, seed, pixels):
    """(image, seconds from the loaded scene to the image in numpy, extras)."""
    extra = dict(load_s=fresh.load(), loadavg=os.getloadavg()[0])
    dr.kernel_history()              # (clears it)
    t0 = time.perf_counter()
    integ = mi.load_dict(integrator_of(method, spp, pixels))
    image = np.array(mi.render(fresh.scene, integrator=integ, spp=spp, seed=seed), dtype=np.float64)
    seconds = time.perf_counter() - t0
    extra["compile_s"] = compile_seconds()
    extra["seconds_nc"] = max(seconds - extra["compile_s"], 1e-6)
    cached = getattr(integ, "_cached", None)
    if cached:
        extra["solve_s"] = cached[1].meta.get("seconds")
    fresh.check_fresh(method)
    if not np.all(np.isfinite(image)):
        raise RuntimeError("%s: non-finite pixels at %d spp" % (method, spp))
    return image, seconds, extra


def setup_seconds(d, method):
    """Seconds of the patch table and of the display's field on a freshly loaded scene."""
    from mi_plugins.solution import patchfield
    scene, integ = mi.load_dict(d), mi.load_dict(PACKAGE[method])
    t0 = time.perf_counter()
    table = integ.patch_table(scene)
    t1 = time.perf_counter()
    out = dict(patch_table_s=t1 - t0, patches=int(table.count))
    if integ.display != "gather":
        patchfield.field_of(table)
        out["field_s"] = time.perf_counter() - t1
    return out


def round_up(budget):
    """``budget`` rounded up to a multiple of the largest power of two at most an eighth of
    it (1754 -> 1792 = 7 x 256): a render is split into passes of a divisor of its camera
    samples (``display.pass_layout``), and a count like 1754 = 2 x 877 leaves passes of 2
    (at 128 x 96 px ``ray_bundle``'s smooth display took 71 s for what 1024 spp did in 10 s)."""
    step = 1 << max(int(budget // 8).bit_length() - 1, 0)
    return -(-int(budget) // step) * step


def next_budget(rungs, t_max, cap, spp_of_budget):
    """(the next budget, None) or (None, why the ladder stops): 'done' once a budget's median
    render takes ``t_max`` (compilation excluded, as the ratios). Seconds(spp) ~ a + c spp
    from the last two budgets; the next budget doubles, or where doubling would pass
    1.3 t_max, is the one predicted to take 1.15 t_max; none predicted above ``cap``."""
    med = lambda rung: float(np.median([r["seconds_nc"] for r in rung["renders"]]))
    last, t = rungs[-1], med(rungs[-1])
    if t >= t_max:
        return None, "done"
    spp = last["spp"]
    if len(rungs) > 1 and last["spp"] > rungs[-2]["spp"]:
        c = max((t - med(rungs[-2])) / (spp - rungs[-2]["spp"]), 1e-9)
    else:
        c = t / spp
    a = max(t - c * spp, 0.0)
    budget = 2 * last["budget"]
    while spp_of_budget(budget) <= spp:
        budget *= 2
    if a + c * spp_of_budget(budget) > 1.3 * t_max:
        target = int(np.ceil((1.15 * t_max - a) / c * last["budget"] / spp))
        budget = round_up(max(target, int(1.25 * last["budget"]) + 1))
        while spp_of_budget(budget) <= spp:
            budget += max(1, budget // 8)
    if a + c * spp_of_budget(budget) > cap:
        return None, "next budget (%d spp) predicted above --cap %g s" % (spp_of_budget(budget), cap)
    return budget, None


def ladder(args, sname, method):
    say = lambda s: print("  %s / %s: %s" % (sname, method, s), file=sys.stderr, flush=True)
    d = interiors.scene_dict(sname, args.resolution, sampler=sampler_of(method))
    pixels = d["sensor"]["film"]["width"] * d["sensor"]["film"]["height"]
    ref, ref_var, keep = reference(args, sname)
    dr.set_flag(dr.JitFlag.KernelHistory, True)      # (cleared at every render)
    warm = Fresh(d)
    _, warm_s, _ = timed(warm, method, spp_of(method, 1), 999, pixels)
    del warm
    gc.collect()
    out = dict(method=method, triangles=interiors.triangles(sname), warmup_s=warm_s, rungs=[], stopped=None,
               kept=float(keep.mean()))
    if method in PACKAGE:
        out["setup"] = setup_seconds(d, method)
        gc.collect()
    say("warm-up %.1f s%s" % (warm_s, "; setup %s" % out.get("setup", "")))
    fresh, budget = Fresh(d), 1
    while True:
        spp = spp_of(method, budget)
        renders, images = [], []
        for k in range(args.seeds):
            image, seconds, extra = timed(fresh, method, spp, 1 + k + 100 * len(out["rungs"]), pixels)
            rmse, rmse_x = report.errors(image, ref, ref_var, keep)
            renders.append(dict(seed_index=k, seconds=seconds, rmse=rmse, rmse_x=rmse_x, **extra))
            images.append(image)
            say("%d spp, seed %d: %.2f s, RMSE %.4g (away %.4g), load %.1f%s" % (
                spp, k, seconds, rmse, rmse_x, extra["loadavg"],
                ", compiled %.2f s" % extra["compile_s"] if extra["compile_s"] else ""))
        out["rungs"].append(dict(budget=budget, spp=spp, renders=renders,
                                 **report.split(images, ref, ref_var, keep)))
        nxt, stop = next_budget(out["rungs"], max(args.times), args.cap, lambda b: spp_of(method, b))
        if stop or len(out["rungs"]) >= args.max_rungs:
            out["stopped"] = None if stop == "done" else stop or "at --max-rungs"
            break
        budget = nxt
    return out
