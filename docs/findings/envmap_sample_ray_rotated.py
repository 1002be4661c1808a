"""Mitsuba 3.9.1: `envmap.sample_ray` with a rotated map puts the ray origins on the wrong disk

Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0, variant llvm_ad_rgb (CPU, LLVM backend).

Scene: a unit `sphere` at the origin and an `envmap` of constant radiance 1 (a 32 x 16
bitmap of ones) with `to_world` a rotation about the x axis by 0, 45 or 90 degrees. A
constant map is invariant under rotation, so nothing may change with the angle.

Expected: the power that the rays of `Emitter.sample_ray` deliver to the sphere,
E[weight * (ray hits the sphere)], is the incident flux pi L * 4 pi r^2 = 4 pi^2 = 39.478
at every angle; a light tracer (`ptracer`) renders the same image as `path`.

Measured (2^20 rays per angle; `ptracer` vs `path`: 8 renders of 16 x 16 px, 256 spp,
diffuse ball of albedo 1/2, `max_depth` 2, emitters hidden):

    Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb
    rotation  0 deg: flux on the ball 39.483 +- 0.055   expected 39.478   ratio 1.000   z = +0.1   ray origins inside the bounding sphere: 0.0 %
    rotation 45 deg: flux on the ball 49.602 +- 0.057   expected 39.478   ratio 1.256   z = +177.4   ray origins inside the bounding sphere: 27.1 %
    rotation 90 deg: flux on the ball 73.217 +- 0.056   expected 39.478   ratio 1.855   z = +600.3   ray origins inside the bounding sphere: 35.8 %
    rotation  0 deg: image mean path 0.1562 +- 0.0001, ptracer 0.1559 +- 0.0005   ratio 0.998   z = -0.6
    rotation 90 deg: image mean path 0.1562 +- 0.0001, ptracer 0.2357 +- 0.0008   ratio 1.509   z = +102.7
    (1.5 s)

Unrotated, the flux is exact; rotated by 45 degrees it is 1.26x too high, by 90 degrees
1.85x, and 27 % and 36 % of the ray origins lie inside the scene's bounding sphere (none
unrotated). `ptracer`'s image of the ball is 1.5x too bright under the rotated map;
`path` does not change.

Cause (src/emitters/envmap.cpp, `EnvironmentMapEmitter::sample_ray`): the direction is
sampled in the map's local frame (`d`) and rotated into the world (`d_global =
m_to_world * -d`), but the ray origin's offset on the disk is built in the frame of the
local direction: `perpendicular_offset = Frame3f(d).to_world(Vector3f(offset.x(),
offset.y(), 0))`. With a rotation the disk is no longer perpendicular to the ray
direction: its projection across the rays is an ellipse of area pi R^2 |cos beta| while
the weight still assumes pi R^2, so the particle density (and power) per unit area rises
by 1/|cos beta|, and origins can move inside the bounding sphere.

Suggested fix: build the disk around the world direction, `Frame3f(d_global)` (or rotate
the offset with `m_to_world` as well).

Run: `python docs/findings/envmap_sample_ray_rotated.py` (about 3 s on 2 cores).
"""
import time

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant("llvm_ad_rgb")


def environment(angle):
    return {"type": "envmap", "bitmap": mi.Bitmap(np.ones((16, 32, 3), dtype=np.float32)),
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], angle)}


def flux_on_ball(angle, n=1 << 20):
    scene = mi.load_dict({"type": "scene", "ball": {"type": "sphere", "radius": 1.0}, "env": environment(angle)})
    emitter = scene.emitters()[0]
    rng = mi.PCG32(n)
    u = rng.next_float32
    ray, weight = emitter.sample_ray(0.0, u(), mi.Point2f(u(), u()), mi.Point2f(u(), u()))
    hit = scene.ray_intersect(ray).is_valid()
    power = np.array(dr.select(hit, weight[0], 0.0), dtype=np.float64)
    bsphere = scene.bbox().bounding_sphere()
    inside = np.mean(np.array(dr.norm(ray.o - mi.Point3f(bsphere.center))) < bsphere.radius)
    return power.mean(), power.std() / np.sqrt(n), inside


def ball_image(integrator, angle):
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": integrator, "max_depth": 2, "hide_emitters": True},
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 6], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "ball": {"type": "sphere", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
        "env": environment(angle)})
    runs = np.array([np.mean(np.array(mi.render(scene, spp=256, seed=s), dtype=np.float64)) for s in range(8)])
    return runs.mean(), runs.std(ddof=1) / np.sqrt(len(runs))


def main():
    start = time.time()
    print("Mitsuba %s, Dr.Jit %s, %s" % (mi.__version__, dr.__version__, mi.variant()))
    exact = 4 * np.pi ** 2
    for angle in (0, 45, 90):
        mean, se, inside = flux_on_ball(angle)
        print("rotation %2d deg: flux on the ball %.3f +- %.3f   expected %.3f   ratio %.3f   z = %+.1f   "
              "ray origins inside the bounding sphere: %.1f %%"
              % (angle, mean, se, exact, mean / exact, (mean - exact) / se, 100 * inside))
    for angle in (0, 90):
        (p, p_se), (t, t_se) = ball_image("path", angle), ball_image("ptracer", angle)
        print("rotation %2d deg: image mean path %.4f +- %.4f, ptracer %.4f +- %.4f   ratio %.3f   z = %+.1f"
              % (angle, p, p_se, t, t_se, t / p, (t - p) / np.hypot(p_se, t_se)))
    print("(%.1f s)" % (time.time() - start))


if __name__ == "__main__":
    main()
