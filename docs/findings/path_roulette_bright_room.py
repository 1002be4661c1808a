"""Mitsuba 3.9.1: `path`'s Russian roulette has infinite variance in rooms of reflectance above 0.975

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

A closed room (a `cube` with `flip_normals`, `diffuse` reflectance 0.99) lit by a small
`area` lamp under its ceiling, seen from inside: an ordinary high-albedo interior (white
plaster is about 0.9; snow, white paint and the furnace-style tests of integrators go
above 0.97).

Expected: `path` with its defaults converges to the image that `path` without roulette
gives (`rr_depth` beyond `max_depth`, 3000 bounces: 0.99^3000 = 1e-13 of the light left
out), with a standard error that falls as 1 / sqrt(spp).

Measured (image means of 8 x 8 px renders, 12 seeds of 256 spp with the defaults; 8 seeds
of 64 spp without roulette; +- is the standard error of the mean):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    reflectance 0.90  no roulette: 0.3714 +- 0.0004   defaults: 0.3699 +- 0.0007 (z = -1.8), single renders 0.366 .. 0.375 (spread 0.7 %)
    reflectance 0.99  no roulette: 3.9219 +- 0.0021   defaults: 3.4169 +- 0.0954 (z = -5.3), single renders 3.167 .. 4.277 (spread 9.7 %)
    (12.6 s)

With the defaults the means of single renders spread by about 10 % and fall below the
reference on average: a few rare paths carry a large part of the light (a heavy tail),
and most runs miss them. At reflectance 0.9 the same comparison agrees.

Cause (src/integrators/path.cpp, `PathIntegrator::sample`): the roulette survives with
q = min(max(throughput) * eta^2, 0.95) and divides the throughput by q. Once the
throughput has reached 0.95, a bounce of albedo a > 0.95 leaves it at a / 0.95 times its
value: a path of k more bounces survives with probability 0.95^k and carries (a / 0.95)^k,
so the estimator's second moment sums (a^2 / 0.95)^k and diverges for a^2 > 0.95, i.e.
a > 0.975. The mean stays right in theory, but its variance is infinite, and finite runs
are biased low in practice.

Suggested fix: let q reach 1 for throughputs of 1 (q = min(max(throughput) * eta^2, 1) with
a bounce cap, or a cap closer to 1 such as 0.99, which keeps the variance finite up to
a = 0.995), or document the limit next to `rr_depth`. (`ptracer` and `volpath` share the
rule.)

Run: `python docs/findings/path_roulette_bright_room.py` (about 13 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")


def room(albedo, integrator):
    t = mi.ScalarTransform4f()
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "box": {"type": "cube", "flip_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}}},
        "lamp": {"type": "rectangle", "to_world": t.translate([0, 0.99, 0]).rotate([1, 0, 0], 90).scale(0.05),
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [100.0] * 3}}},
        "sensor": {"type": "perspective", "fov": 70,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 0.9], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}}})


def means(scene, spp, seeds):
    return np.array([float(np.mean(np.array(mi.render(scene, spp=spp, seed=s))[..., :3])) for s in range(seeds)])


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for albedo in (0.9, 0.99):
        ref = means(room(albedo, {"type": "path", "max_depth": 3000, "rr_depth": 100000}), 64, 8)
        got = means(room(albedo, {"type": "path"}), 256, 12)
        se_ref, se = ref.std(ddof=1) / np.sqrt(len(ref)), got.std(ddof=1) / np.sqrt(len(got))
        print("reflectance %.2f  no roulette: %.4f +- %.4f   defaults: %.4f +- %.4f (z = %+.1f), "
              "single renders %.3f .. %.3f (spread %.1f %%)"
              % (albedo, ref.mean(), se_ref, got.mean(), se, (got.mean() - ref.mean()) / np.hypot(se, se_ref),
                 got.min(), got.max(), 100 * got.std(ddof=1) / got.mean()))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
