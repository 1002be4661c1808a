"""Light rays for the package's light tracers (``stochastic_ray``, ``qmc_lighttrace``).

:func:`sample_light_rays` picks an emitter, then a ray leaving it and the power it
carries, from five numbers in [0, 1): Mitsuba's ``Emitter.sample_ray`` for surface and
delta lights; for environment and directional lights (``envmap``, ``constant``,
``sunsky``, ``directional``) a direction from ``sample_direction`` and a point of a disk
across the scene's bounding sphere perpendicular to it. The latter replaces Mitsuba
3.9.1's own ``envmap`` ray sampling, which tilts that disk when the map is rotated
(``to_world``): the power of every ray is then wrong (README, Findings).
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


def has_infinite(scene):
    return any(mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) for e in scene.emitters())


def sample_light_rays(scene, u_emitter, u_position, u_direction, active=True):
    """(ray, power) of light rays: ``u_emitter`` (Float) chooses the emitter,
    ``u_position`` and ``u_direction`` (Point2f) the ray. The power (Color3f) includes the
    probability of the emitter's choice; zero where ``active`` is false."""
    index, choice_weight, u_reused = scene.sample_emitter(u_emitter, active)
    emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), index, active)
    position = mi.Point2f(u_reused, u_position.y)
    ray, power = emitter.sample_ray(0.0, 0.5, position, u_direction, active)
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
