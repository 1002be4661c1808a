"""Light rays for the package's light tracers (``stochastic_ray``, ``qmc_lighttrace``).

:func:`sample_light_rays` picks an emitter, then a ray leaving it and the power it
carries, from five numbers in [0, 1): Mitsuba's ``Emitter.sample_ray`` for delta lights
and the package's surface lights; for textured ``area`` lights a point uniform on the shape
(``Shape.sample_position``) and a cosine-distributed direction, weighted by the
radiance there (Mitsuba 3.9.1's ``area`` samples a textured radiance in the texture's
uv space and maps it onto the shape through its uv parameterization: on a mesh whose uv
map is not one-to-one, e.g. with seams, almost every sample is lost and the rays carry a
few per mille of the light's power, docs/findings.md); for environment and directional lights (``envmap``, ``constant``,
``sunsky``, ``directional``) a direction from ``sample_direction`` and a point of a disk
across the scene's bounding sphere perpendicular to it. The latter replaces Mitsuba
3.9.1's own ``envmap`` ray sampling, which tilts that disk when the map is rotated
(``to_world``): the power of every ray is then wrong (docs/findings.md).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.meshtable import scene_bounds


def bounding_sphere(scene):
    """(centre, radius) of a sphere around every shape of ``scene``, slightly enlarged
    (from :func:`mi_plugins.meshtable.scene_bounds`: ``scene.bbox()`` misses the meshes
    Mitsuba merges)."""
    lo, hi = scene_bounds(scene)
    center = 0.5 * (lo + hi)
    return mi.Point3f(*(float(c) for c in center)), float(np.linalg.norm(hi - lo)) * 0.5 * 1.001 + 1e-4


def area_lights(scene):
    """Per emitter index, whether it is Mitsuba's ``area`` light with a spatially varying
    radiance (a texture, not one value: the lights whose own ray sampling goes through the
    uv parameterization), as a Bool array; None where the scene has none."""
    flags = [e.class_name() == "AreaLight" and "radiance.value" not in mi.traverse(e).keys()
             for e in scene.emitters()]
    return mi.Bool(flags) if any(flags) else None


def _area_light_rays(emitter, position, u_direction, active):
    """Rays of ``area`` lights: a point uniform on the shape, a cosine-distributed
    direction around its normal, the power L pi / pdf (unbiased for any radiance)."""
    shape = emitter.get_shape()
    ps = shape.sample_position(0.0, position, active)
    local = mi.warp.square_to_cosine_hemisphere(u_direction)
    si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
    si.wi = local
    si.shape = shape
    radiance = emitter.eval(si, active)
    weight = dr.select(active & (ps.pdf > 0), radiance * dr.pi / ps.pdf, 0.0)
    return mi.Ray3f(ps.p, mi.Frame3f(ps.n).to_world(local)), weight


def has_infinite(scene):
    return any(mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) for e in scene.emitters())


def sample_light_rays(scene, u_emitter, u_position, u_direction, active=True):
    """(ray, power) of light rays: ``u_emitter`` (Float) chooses the emitter,
    ``u_position`` and ``u_direction`` (Point2f) the ray. The power (Color3f) includes the
    probability of the emitter's choice; zero where ``active`` is false."""
    index, choice_weight, u_reused = scene.sample_emitter(u_emitter, active)
    emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), index, active)
    position = mi.Point2f(u_reused, u_position.y)
    area = area_lights(scene)
    if area is None or not dr.all(area):
        # (not where every emitter is a textured area light: Mitsuba's sample_ray of some
        # textures, e.g. checkerboard, raises 'not implemented')
        ray, power = emitter.sample_ray(0.0, 0.5, position, u_direction, active)
    if area is not None:
        uniform = active & dr.gather(mi.Bool, area, index, active)
        ray_a, power_a = _area_light_rays(emitter, position, u_direction, uniform)
        if dr.all(area):
            ray, power = ray_a, power_a
        else:
            ray = dr.select(uniform, ray_a, ray)
            power = dr.select(uniform, power_a, power)
    if has_infinite(scene):
        center, r = bounding_sphere(scene)
        it = dr.zeros(mi.Interaction3f)
        it.p = center
        infinite = active & mi.has_flag(emitter.flags(), mi.EmitterFlags.Infinite)
        ds, radiance = emitter.sample_direction(it, u_direction, infinite)
        disk = mi.warp.square_to_uniform_disk_concentric(position)
        origin = center + (ds.d + mi.Frame3f(ds.d).to_world(mi.Vector3f(disk.x, disk.y, 0))) * r
        ray = dr.select(infinite, mi.Ray3f(origin, -ds.d), ray)
        power = dr.select(infinite, radiance * (dr.pi * r * r), power)
    return ray, dr.select(active, mi.Color3f(power * choice_weight), 0.0)
