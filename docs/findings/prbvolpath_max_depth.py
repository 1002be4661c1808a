"""Mitsuba 3.9.1: `prbvolpath` with a finite `max_depth` D renders part of one bounce too many

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene: the white furnace inside Mitsuba's `cube` (`flip_normals`), `diffuse` albedo
a = 1/2, `area` emitter Le = 1/2, no media. With at most D path vertices every pixel is
exactly L = Le (1 + a + ... + a^(D-1)): 0.5 at D = 1, 0.75 at D = 2, 0.984375 at D = 6;
the derivative w.r.t. the albedo at D = 6 is Le * sum_{k<6} k a^(k-1) = 1.78125.

Expected: `prbvolpath` gives those values, like `volpath` (and `prb`).

Measured (16 renders of 8 x 8 px, 256 spp; derivatives: 8 reverse-mode renders of 64 spp,
d(image mean)/da with the albedo moved in all channels; +- is the standard error):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    volpath, max_depth 1             0.5000 (every run exactly)
    prbvolpath, max_depth 1          0.6666 +- 0.0001   expected 0.500000   z = +1236.0
    volpath, max_depth 2             0.7501 +- 0.0002   expected 0.750000   z = +0.4
    prbvolpath, max_depth 2          0.8346 +- 0.0002   expected 0.750000   z = +351.8
    volpath, max_depth 6             0.9846 +- 0.0002   expected 0.984375   z = +1.3
    prbvolpath, max_depth 6          0.9897 +- 0.0003   expected 0.984375   z = +20.9
    prb dL/da, max_depth 6           1.7804 +- 0.0019   expected 1.781250   z = -0.5
    prbvolpath dL/da, max_depth 6    1.8421 +- 0.0019   expected 1.781250   z = +31.2
    (7.2 s)

`prbvolpath` adds about a third of the next bounce: 0.666 at D = 1 (exact 0.5), 0.835 at
D = 2 (0.75), and the derivative at D = 6 is 3.4 % too high, while `volpath` and `prb` are
exact.

Cause (python/ad/integrators/prbvolpath.py, `PRBVolpathIntegrator.sample`): in the loop
body, `active_surface = active & ~active_medium` is computed at the top of the iteration,
and `active &= depth < self.max_depth` comes later ("Don't estimate lighting if we
exceeded number of bounces"), without updating `active_surface`. The iteration that
starts at depth D therefore still intersects the BSDF-sampled ray and adds the emission
it finds, MIS-weighted with `mis_weight(last_scatter_direction_pdf, emitter_pdf)`, while
the matching next-event estimate at depth D - 1 was (correctly) skipped by
`depth + 1 < self.max_depth`. In a surface-only scene depth only advances after the
surface interaction, so the extra term is the BSDF-sampled half of bounce D.

Suggested fix: apply the depth limit before deriving the surface/medium masks, e.g.
`active_surface &= active` (and the same for the medium branch) right after
`active &= depth < self.max_depth`, or test `depth < self.max_depth` when computing
`active_surface` for the emission step.

Run: `python docs/findings/prbvolpath_max_depth.py` (about 10 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

A, LE = 0.5, 0.5
KEY = "walls.bsdf.reflectance.value"


def furnace(integrator, res=8):
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": mi.ScalarTransform4f().look_at([0.4, 0.3, 0.8], [-0.6, -0.4, -1.0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "walls": {"type": "cube", "flip_normals": True,
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": A}},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": LE}}}})


def report(label, values, expected):
    mean, se = values.mean(), values.std(ddof=1) / np.sqrt(len(values))
    print("%-32s %.4f +- %.4f   expected %.6f   z = %+.1f" % (label, mean, se, expected, (mean - expected) / se))


def albedo_derivative(scene, spp, seed):
    """Reverse mode: d(image mean)/da, the albedo moved in all channels."""
    params = mi.traverse(scene)
    theta = dr.zeros(mi.Color3f, 1)
    dr.enable_grad(theta)
    params[KEY] = mi.Color3f(A) + theta
    params.update()
    dr.backward(dr.mean(mi.render(scene, params, spp=spp, seed=seed), axis=None))
    return float(np.sum(np.array(dr.grad(theta))))


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for depth in (1, 2, 6):
        for name in ("volpath", "prbvolpath"):
            scene = furnace({"type": name, "max_depth": depth})
            runs = np.array([np.mean(np.array(mi.render(scene, spp=256, seed=s), dtype=np.float64)) for s in range(16)])
            expected = LE * sum(A ** k for k in range(depth))
            if name == "volpath" and np.all(runs == expected):
                print("%-32s %.4f (every run exactly)" % ("%s, max_depth %d" % (name, depth), expected))
            else:
                report("%s, max_depth %d" % (name, depth), runs, expected)
    expected = LE * sum(k * A ** (k - 1) for k in range(1, 6))
    for name in ("prb", "prbvolpath"):
        scene = furnace({"type": name, "max_depth": 6})
        report("%s dL/da, max_depth 6" % name, np.array([albedo_derivative(scene, 64, s) for s in range(8)]), expected)
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
