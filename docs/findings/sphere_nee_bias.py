"""Mitsuba 3.9.1: next-event estimation on the analytic `sphere` from points on that sphere is biased (+0.14 % per bounce)

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene (the white furnace inside a sphere): an analytic `sphere` with `flip_normals`,
a `diffuse` BSDF of albedo a = 1/2 and an `area` emitter of radiance Le = 1/2; the
camera is inside. Every surface point emits Le and reflects a fraction a of the
(uniform) incident radiance, so with at most D path vertices the radiance is exactly
L = Le (1 + a + ... + a^(D-1)) in every pixel, whatever the shape: 0.75 at
`max_depth` 2, 0.875 at 3. The same furnace built from Mitsuba's `cube` (a triangle
mesh) is the control.

Expected: `path` gives 0.75 (D = 2) and 0.875 (D = 3) up to noise.

Measured (16 renders of 16 x 16 px, 1024 spp each; +- is the standard error of the mean):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    path, sphere furnace, max_depth 2      0.751076 +- 0.000006   expected 0.750000   z = +186.1
    path, sphere furnace, max_depth 3      0.876384 +- 0.000007   expected 0.875000   z = +205.8
    path, cube furnace, max_depth 2        0.750027 +- 0.000045   expected 0.750000   z = +0.6
    path, cube furnace, max_depth 3        0.875003 +- 0.000048   expected 0.875000   z = +0.1
    ptracer, sphere furnace, max_depth 2   0.749982 +- 0.000746   expected 0.750000   z = -0.0
    ptracer, sphere furnace, max_depth 3   0.875049 +- 0.000781   expected 0.875000   z = +0.1
    emitter samples from points on the sphere whose pdf_emitter_direction differs from ds.pdf by > 0.1 %: 2.20 % of 1048576
    prb dL/dLe, sphere furnace, D = inf    2.003039 +- 0.000316   expected 2.000000   z = +9.6
    (12.7 s)

`ptracer` (no emitter sampling from surface points) and `path` on the `cube` furnace
are exact; `path` on the sphere reads +0.14 % (D = 2) and +0.16 % (D = 3), z > 100.
Reverse-mode `prb` inherits the bias in the derivative dL/dLe.

Cause (src/shapes/sphere.cpp): `SphereShape::sample_direction` decides whether the
reference point is inside the sphere with the radius enlarged by `RayEpsilon`
(`radius_adj = radius * (1 + RayEpsilon)` when `flip_normals` is set) and then samples
the sphere's area uniformly, while `SphereShape::pdf_direction` decides it with
`sin_alpha < OneMinusEpsilon` and returns the cone pdf for "outside" points. For a
reference point on the sphere itself (float error of about 1e-7 in |p - c|) the two tests
disagree for a few percent of the points (the script counts the samples whose
`pdf_emitter_direction` differs from the `ds.pdf` returned by `sample_emitter_direction`),
so the MIS weights of emitter sampling and BSDF sampling no longer sum to one.

Suggested fix: use one and the same inside/outside test in `sample_direction` and
`pdf_direction` (e.g. compute `dc_2 > radius_adj^2` in both), so that a direction's pdf
is the pdf it was sampled with.

Run: `python docs/findings/sphere_nee_bias.py` (about 14 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

A, LE = 0.5, 0.5


def furnace(integrator, shape="sphere", res=16):
    return mi.load_dict({
        "type": "scene", "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": mi.ScalarTransform4f().look_at([0.3, 0.2, 0.4], [-0.5, -0.1, -1.0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "walls": {"type": shape, "flip_normals": True,
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": A}},
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": LE}}}})


def exact(max_depth):
    return LE * sum(A ** k for k in range(max_depth))


def report(label, values, expected):
    mean, se = values.mean(), values.std(ddof=1) / np.sqrt(len(values))
    print("%-38s %.6f +- %.6f   expected %.6f   z = %+.1f" % (label, mean, se, expected, (mean - expected) / se))


def image_means(scene, spp, runs):
    return np.array([np.mean(np.array(mi.render(scene, spp=spp, seed=s), dtype=np.float64)) for s in range(runs)])


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    for integrator, shape, spp in [("path", "sphere", 1024), ("path", "cube", 1024), ("ptracer", "sphere", 1024)]:
        for depth in (2, 3):
            scene = furnace({"type": integrator, "max_depth": depth}, shape)
            report("%s, %s furnace, max_depth %d" % (integrator, shape, depth), image_means(scene, spp, 16), exact(depth))

    # The cause: the pdf a direction was sampled with vs. the pdf Mitsuba evaluates for it.
    scene = furnace({"type": "path"}, "sphere")
    n = 1 << 20
    rng = mi.PCG32(n)
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(rng.next_float32(), rng.next_float32()))
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(0.1, -0.2, 0.05), d))
    ds, _ = scene.sample_emitter_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), False)
    sampled, evaluated = np.array(ds.pdf), np.array(scene.pdf_emitter_direction(si, ds))
    ok = np.isfinite(sampled) & (sampled > 0)
    print("emitter samples from points on the sphere whose pdf_emitter_direction differs from ds.pdf "
          "by > 0.1 %%: %.2f %% of %d" % (100 * np.mean(np.abs(evaluated[ok] / sampled[ok] - 1) > 1e-3), n))

    # The derivative inherits the bias: d L / d Le with prb (reverse mode), unbounded depth: exact 1/(1-a) = 2.
    scene = furnace({"type": "prb", "max_depth": -1}, "sphere", res=8)
    params = mi.traverse(scene)
    key = "walls.emitter.radiance.value"
    values = []
    for s in range(16):
        theta = dr.zeros(mi.Color3f, 1)
        dr.enable_grad(theta)
        params[key] = mi.Color3f(LE) + theta
        params.update()
        dr.backward(dr.mean(mi.render(scene, params, spp=256, seed=s), axis=None))
        values.append(float(np.sum(np.array(dr.grad(theta)))))
    report("prb dL/dLe, sphere furnace, D = inf", np.array(values), 1 / (1 - A))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
