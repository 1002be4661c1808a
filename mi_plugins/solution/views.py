"""Many views from one solution: every sensor of a scene, or a camera path.

The finite-element integrators (``ray_bundle``, ``qmc_lighttrace``) keep the solution of
the last scene and seed they rendered (``integrators.solving``), so rendering the views
of one scene with one seed solves once and displays every view::

    images = views.render_views(scene, {'type': 'qmc_lighttrace', 'display': 'smooth'}, sensors="all", spp=16)
    path = views.orbit(scene, frames=60)                      # to_world transforms around the scene
    images = views.render_camera_path(scene, integrator, path, spp=16)

Any Mitsuba integrator works the same way (each view then renders on its own).
"""
import mitsuba as mi
import numpy as np


def _integrator(scene, integrator):
    if integrator is None:
        integrator = scene.integrator()
    elif isinstance(integrator, dict):
        integrator = mi.load_dict(integrator)
    if integrator is None:
        raise ValueError("views: the scene has no integrator; pass one (a plugin dict or a loaded integrator)")
    return integrator


def sensor_list(scene, sensors="all"):
    """The sensors ``sensors`` names: 'all', an index, or a list of indices, sensor dicts
    and sensor objects."""
    own = list(scene.sensors())
    if isinstance(sensors, str):
        if sensors != "all":
            raise ValueError("sensors=%r: valid: 'all', an index 0 .. %d, or a list of indices, sensor dicts and "
                             "sensors" % (sensors, len(own) - 1))
        return own
    items = [sensors] if isinstance(sensors, (int, dict, mi.Sensor)) else list(sensors)
    out = []
    for item in items:
        if isinstance(item, (int, np.integer)):
            if not 0 <= int(item) < len(own):
                raise ValueError("sensor index %d: the scene has %d sensor(s) (valid: 0 .. %d)"
                                 % (item, len(own), len(own) - 1))
            out.append(own[int(item)])
        elif isinstance(item, dict):
            out.append(mi.load_dict(item))
        else:
            out.append(item)
    return out


def render_views(scene, integrator=None, sensors="all", spp=0, seed=0):
    """The images (``mi.TensorXf``) of ``scene`` seen by each of ``sensors``
    (:func:`sensor_list`) with ``integrator`` (None: the scene's), one seed for all: a
    finite-element integrator solves once."""
    integ = _integrator(scene, integrator)
    return [mi.render(scene, integrator=integ, sensor=sensor, spp=int(spp), seed=int(seed))
            for sensor in sensor_list(scene, sensors)]


def orbit(scene, frames, sensor=0, turns=1.0, axis=(0.0, 1.0, 0.0), center=None):
    """``frames`` camera transforms (``mi.ScalarTransform4f``) circling ``center`` (default:
    the centre of the scene's shapes) about ``axis`` through it, starting from the
    transform of the scene's sensor ``sensor`` and keeping its distance, height and up
    direction: ``turns`` full turns over the frames."""
    from mi_plugins.base.queries import scene_bounds
    base = scene.sensors()[sensor]
    m = np.array(mi.traverse(base)["to_world"].matrix, dtype=np.float64).reshape(4, 4)
    origin, forward, up = m[:3, 3], m[:3, 2], m[:3, 1]
    if center is None:
        lo, hi = scene_bounds(scene)
        center = 0.5 * (lo + hi)
    center, axis = np.asarray(center, dtype=np.float64), np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    out = []
    for k in range(int(frames)):
        angle = 2.0 * np.pi * turns * k / max(int(frames), 1)
        rot = _rotation(axis, angle)
        o = center + rot @ (origin - center)
        out.append(mi.ScalarTransform4f().look_at(origin=o.tolist(), target=(o + rot @ forward).tolist(),
                                                   up=(rot @ up).tolist()))
    return out


def _rotation(axis, angle):
    x, y, z = axis
    c, s = np.cos(angle), np.sin(angle)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) * c + s * k + (1 - c) * np.outer(axis, axis)


def render_camera_path(scene, integrator, transforms, spp=0, seed=0, sensor=0):
    """The images of ``scene`` from the scene's sensor ``sensor`` moved along ``transforms``
    (``to_world`` of each frame, e.g. :func:`orbit`), one seed for all frames; the sensor's
    own transform is restored afterwards."""
    integ = _integrator(scene, integrator)
    cam = scene.sensors()[sensor]
    params = mi.traverse(cam)
    original = mi.ScalarTransform4f(np.array(params["to_world"].matrix, dtype=np.float32).reshape(4, 4))
    images = []
    try:
        for transform in transforms:
            params["to_world"] = transform
            params.update()
            images.append(mi.render(scene, integrator=integ, sensor=cam, spp=int(spp), seed=int(seed)))
    finally:
        params["to_world"] = original
        params.update()
    return images
