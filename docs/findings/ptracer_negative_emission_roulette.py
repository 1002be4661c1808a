"""Mitsuba 3.9.1: `ptracer`'s Russian roulette kills every light path of negative weight

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Negative emission is legitimate in linear transport (difference images, control
variates, signed emission estimates such as the simulated emission of our package's
`simulated_area` emitter, where the finding was first seen). Here it is expressed with
Mitsuba's own plugins only: the furnace inside a `cube` (`flip_normals`) with a `diffuse`
BSDF of albedo a = 0.9 and an `area` emitter of constant radiance Le = +1 or Le = -1.
Every pixel then sees exactly L = Le / (1 - a) = +-10, and transport is linear:
the Le = -1 image must be the negative of the Le = +1 image.

Expected: `ptracer` gives +10 and -10, like `path`.

Measured (8 renders of 8 x 8 px, 64 spp each; +- is the standard error of the mean):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    type=path                        Le = +1:   9.9641 +- 0.0528   expected +10.0000   z = -0.7
    type=path                        Le = -1:  -9.9641 +- 0.0528   expected -10.0000   z = +0.7
    type=ptracer                     Le = +1:  10.0310 +- 0.0294   expected +10.0000   z = +1.1
    type=ptracer                     Le = -1:  -4.7102 +- 0.0249   expected -10.0000   z = +212.6
    type=ptracer, rr_depth=1000      Le = +1:  10.0326 +- 0.0262   expected +10.0000   z = +1.2
    type=ptracer, rr_depth=1000      Le = -1: -10.0326 +- 0.0262   expected -10.0000   z = -1.2
    paths shorter than the roulette depth only: -4.6856
    (12.8 s)

With Le = -1 `ptracer` returns about -4.7, i.e. only the paths shorter than the roulette
depth: -(1 + a + ... + a^5) = -4.69. With `rr_depth` 1000 (roulette never starts) it is
exact, and so is `path`, whose throughputs are non-negative.

Cause (src/integrators/ptracer.cpp, `ParticleTracerIntegrator::trace_light_ray`): the
roulette survival probability is `q = min(max(unpolarized_spectrum(throughput)) * eta^2,
0.95)`. A light path's throughput starts as the emitter's sample weight, negative for
negative emission, so q < 0 and `sampler->next_1d() < q` is never true: every such path
dies at `rr_depth` while the positive paths survive with probability 0.95. The estimator
is no longer unbiased, and the error grows with the albedo.

Suggested fix: take the magnitude, `q = min(max(abs(throughput)) * eta^2, 0.95)` (the
same applies to other integrators that derive q from a signed throughput).

Run: `python docs/findings/ptracer_negative_emission_roulette.py` (about 14 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

A = 0.9


def furnace(integrator, le, res=8):
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": mi.ScalarTransform4f().look_at([0.4, 0.3, 0.8], [-0.6, -0.4, -1.0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "walls": {"type": "cube", "flip_normals": True,
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": A}},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": le}}}})


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for integrator in ({"type": "path"}, {"type": "ptracer"}, {"type": "ptracer", "rr_depth": 1000}):
        for le in (1.0, -1.0):
            scene = furnace(integrator, le)
            runs = np.array([np.mean(np.array(mi.render(scene, spp=64, seed=s), dtype=np.float64)) for s in range(8)])
            mean, se = runs.mean(), runs.std(ddof=1) / np.sqrt(len(runs))
            expected = le / (1 - A)
            label = ", ".join("%s=%s" % kv for kv in integrator.items())
            print("%-32s Le = %+.0f: %8.4f +- %.4f   expected %+.4f   z = %+.1f"
                  % (label, le, mean, se, expected, (mean - expected) / se))
    print("paths shorter than the roulette depth only: %.4f" % -sum(A ** k for k in range(6)))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
