"""Mitsuba 3.9.1: a textured `area` light on a `flip_normals` rectangle gets (almost) no light samples

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene: a diffuse floor (`rectangle` scaled 2, albedo 0.5) and 1 above it a `rectangle`
light scaled 0.3 facing down, with an `area` emitter whose `radiance` is an `rgb` value,
a `checkerboard` or a `bitmap`. The light faces down either by its rotation
("rectangle") or by the opposite rotation and `flip_normals=true` ("flipped"); the
camera looks down at the floor (16 x 16 px, `max_depth` 2: direct light only). Also a
textured light on Mitsuba's own `cube` mesh, and a ceiling 1 above the flipped light
(its dark side).

Expected: `path` agrees with `direct` using BSDF samples only (`emitter_samples` 0,
which never samples the light and is right for any light), flipped or not; the ceiling
above the flipped light stays black (an `area` light emits on its front side only).

Measured (8 renders per value; mean +- standard error):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    flipped rectangle: normal of sample_position [0, -1, 0], of eval_parameterization [0, 1, 0], of a ray hit [0, -1, 0]
    light      radiance      path (NEE + MIS)       direct, BSDF samples only   ratio   z
    rectangle  rgb           0.028291 +- 0.000029   0.028313 +- 0.000105        0.999   -0.2
    rectangle  checkerboard  0.003896 +- 0.000011   0.003893 +- 0.000013        1.001   +0.2
    rectangle  bitmap        0.003982 +- 0.000004   0.003990 +- 0.000015        0.998   -0.5
    flipped    rgb           0.028306 +- 0.000051   0.028313 +- 0.000105        1.000   -0.1
    flipped    checkerboard  0.000012 +- 0.000000   0.003893 +- 0.000017        0.003   -223.4
    flipped    bitmap        0.000014 +- 0.000000   0.003985 +- 0.000014        0.003   -287.7
    cube       bitmap        0.012585 +- 0.000080   0.016087 +- 0.000049        0.782   -37.3
    ceiling above the flipped bitmap light (exact 0): path 0.009639 +- 0.000012, direct BSDF-only 0.000000
    (5.7 s, 3.3 s of CPU)

With a uniform radiance both orientations are right. With a texture, the flipped light
gets 0.3 % of its light through `path` (its BSDF samples that hit the light are weighted
down by MIS against a light-sampling pdf that is not zero, while the light samples
themselves all fail), and its dark side lights the ceiling through light samples
instead. On the `cube` 22 % of the light is missing. `ptracer` is wrong the same way
(`sample_ray` takes the same route; for a checkerboard it raises
`Texture::sample_spectrum(): not implemented!`).

Cause (src/emitters/area.cpp, `AreaLight::sample_direction` and `pdf_direction`): for a
spatially varying radiance the light is sampled in the texture's uv space
(`m_radiance->sample_position`) and mapped onto the shape with
`m_shape->eval_parameterization(uv)`; the sample is kept where `dot(ds.d, ds.n) < 0`
with `ds.n = si.n` of that parameterization. `Rectangle::eval_parameterization`
(src/shapes/rectangle.cpp) returns `si.n = m_frame.n` without `flip_normals`, while
`Rectangle::sample_position` and ray intersections flip it: every sample toward the lit
side is rejected and samples toward the dark side are accepted. `pdf_direction` takes
`ds.n` from the hit (flipped, right) and returns the uv pdf, so MIS discounts the BSDF
samples that do find the light. The same route also loses light wherever the shape's
uv map is not a one-to-one map of the unit square: Mitsuba's `cube` maps each face onto
the whole square (six layers: the pdf is wrong by the overlap), and an obj mesh with uv
seams leaves parts of the square unmapped (those samples are invalid and lost).

Suggested fix: honour `flip_normals` in `Rectangle::eval_parameterization` (negate
`si.n` and the shading frame's normal, as `sample_position` does). More generally, in
`AreaLight::sample_direction` / `pdf_direction` (and `sample_ray`), use the uv route only
for shapes whose parameterization is a bijection of the unit square onto the surface,
and otherwise sample the shape uniformly in area (`Shape::sample_position` /
`pdf_position`), weighting by the radiance there: unbiased for any texture and shape.

Run: `python docs/findings/area_textured_flip_normals_nee.py` (about 6 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")

FLOOR = {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(2),
         "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}}
RADIANCE = {
    "rgb": {"type": "rgb", "value": 4.0},
    "checkerboard": {"type": "checkerboard", "color0": {"type": "rgb", "value": 0.2},
                     "color1": {"type": "rgb", "value": 0.9}},
    "bitmap": {"type": "bitmap", "raw": True, "bitmap": mi.Bitmap(
        np.random.default_rng(1).uniform(0.1, 1.0, (8, 8, 3)).astype(np.float32))},
}
BSDF_ONLY = {"type": "direct", "emitter_samples": 0, "bsdf_samples": 16}


def light(kind, radiance):
    """The light facing down: 'rectangle' (rotated), 'flipped' (rotated up, flip_normals), 'cube'."""
    emitter = {"type": "area", "radiance": RADIANCE[radiance]}
    if kind == "cube":
        return {"type": "cube", "to_world": mi.ScalarTransform4f().translate([0, 1, 0]).scale(0.2), "emitter": emitter}
    d = {"type": "rectangle", "emitter": emitter, "to_world": mi.ScalarTransform4f().translate([0, 1, 0])
         .rotate([1, 0, 0], -90 if kind == "flipped" else 90).scale(0.3)}
    if kind == "flipped":
        d["flip_normals"] = True
    return d


def scene(kind, radiance, integrator, ceiling=False):
    d = {"type": "scene", "integrator": integrator, "floor": FLOOR, "light": light(kind, radiance),
         "sensor": {"type": "perspective", "fov": 50,
                    "to_world": mi.ScalarTransform4f().look_at([0, 3, 3], [0, 0, 0], [0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                    "sampler": {"type": "independent"}}}
    if ceiling:     # a ceiling 1 above the light, seen from below it (the camera between floor and ceiling)
        d["ceiling"] = dict(FLOOR, to_world=mi.ScalarTransform4f().translate([0, 2, 0]).rotate([1, 0, 0], 90).scale(2))
        d["sensor"]["to_world"] = mi.ScalarTransform4f().look_at([0, 1.5, 1.5], [0, 2, 0], [0, 0, -1])
    return mi.load_dict(d)


def mean_se(s, spp, runs=8):
    values = np.array([np.mean(np.array(mi.render(s, spp=spp, seed=k), dtype=np.float64)) for k in range(runs)])
    return values.mean(), values.std(ddof=1) / np.sqrt(runs)


def normals():
    s = mi.load_dict({"type": "scene", "light": light("flipped", "bitmap")})
    shape = s.shapes()[0]
    uv = mi.Point2f(0.3, 0.4)
    hit = s.ray_intersect(mi.Ray3f(mi.Point3f(0, 0, 0), mi.Vector3f(0, 1, 0)))
    fmt = lambda n: "[%g, %g, %g]" % tuple(np.round(np.array(n, dtype=np.float64).ravel(), 6) + 0.0)
    return (fmt(shape.sample_position(0.0, uv).n), fmt(shape.eval_parameterization(uv, mi.RayFlags.All, True).n),
            fmt(hit.n))


def main():
    start, cpu = time.time(), time.process_time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    print("flipped rectangle: normal of sample_position %s, of eval_parameterization %s, of a ray hit %s" % normals())
    print("light      radiance      path (NEE + MIS)       direct, BSDF samples only   ratio   z")
    cases = [(k, r) for k in ("rectangle", "flipped") for r in RADIANCE] + [("cube", "bitmap")]
    for kind, radiance in cases:
        (p, p_se) = mean_se(scene(kind, radiance, {"type": "path", "max_depth": 2}), 64)
        (b, b_se) = mean_se(scene(kind, radiance, BSDF_ONLY), 256)
        print("%-10s %-13s %.6f +- %.6f   %.6f +- %.6f        %.3f   %+.1f"
              % (kind, radiance, p, p_se, b, b_se, p / b, (p - b) / np.hypot(p_se, b_se)))
    (p, p_se) = mean_se(scene("flipped", "bitmap", {"type": "path", "max_depth": 2}, ceiling=True), 64)
    (b, _) = mean_se(scene("flipped", "bitmap", BSDF_ONLY, ceiling=True), 64)
    print("ceiling above the flipped bitmap light (exact 0): path %.6f +- %.6f, direct BSDF-only %.6f" % (p, p_se, b))
    print("(%.1f s, %.1f s of CPU)" % (time.time() - start, time.process_time() - cpu))


if __name__ == "__main__":
    main()
