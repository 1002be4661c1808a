"""The camera of the solution viewer (``mi_plugins.solution.viewer``): a Mitsuba sensor as the
numbers the page's WebGL code projects with, and the same projection in NumPy.

Mitsuba's perspective camera looks along +Z of its ``to_world`` frame, +Y up, +X to the
left of the image. A point with camera coordinates (x, y, z) lands on the film at

    ndc_x = -c x / z - 2 ox,   ndc_y = aspect c y / z + 2 oy     (ndc in [-1, 1], y up)

with c = 1 / tan(x_fov / 2), aspect = film width / height and (ox, oy) the principal
point offset (in film fractions); the page's clip matrix is this with z mapped from
[near_clip, far_clip] to the depth range; the whole film is shown (a crop window is not
applied). ``thinlens`` is shown as its pinhole (no depth of field). A ``to_world`` whose 3 x 3 part is not a rotation (mirrored or not) is
refused: Mitsuba refuses scale factors in it.
"""
import math

import numpy as np

#: sensors the viewer starts from (Mitsuba class names and plugin names)
SENSORS = {"PerspectiveCamera": "perspective", "ThinLensCamera": "thinlens"}


def _value(params, key, default=0.0):
    if key not in params.keys():
        return default
    v = params[key]
    return float(np.array(v).ravel()[0]) if not isinstance(v, (int, float)) else float(v)


def sensor_camera(scene, sensor=0, what="Solution.to_html"):
    """The camera of sensor ``sensor`` (an index into ``scene.sensors()``) as a dict:
    ``eye``, ``axes`` (rows: the unit X (left), Y (up), Z (forward) axes of its frame),
    ``up`` (the coordinate axis nearest to Y: the walkthrough turns about it), ``c``,
    ``aspect``, ``offset`` (ox, oy), ``near``, ``far``, ``width``, ``height`` (film
    pixels), ``mirrored`` (the frame is left-handed)."""
    import mitsuba as mi
    sensors = scene.sensors()
    if isinstance(sensor, bool) or not isinstance(sensor, (int, np.integer)) or not 0 <= sensor < len(sensors):
        raise ValueError("%s: sensor %r; valid range: 0 .. %d (the scene's sensors)" % (what, sensor, len(sensors) - 1))
    s = sensors[int(sensor)]
    kind = s.class_name()
    if kind not in SENSORS:
        raise ValueError("%s: sensor %d is a %s; the viewer starts from a %s sensor"
                         % (what, sensor, kind, " or ".join(repr(v) for v in SENSORS.values())))
    params = mi.traverse(s)
    m = np.array(s.world_transform().matrix, dtype=np.float64).reshape(4, 4)
    frame = m[:3, :3]
    lengths = np.linalg.norm(frame, axis=0)
    if np.abs(frame.T @ frame - np.eye(3)).max() > 1e-4:
        raise ValueError("%s: sensor %d's to_world is not a rotation (column lengths %s); valid: a rotation, "
                         "mirrored or not, and a translation" % (what, sensor, np.round(lengths, 5).tolist()))
    axes = frame.T / lengths[:, None]
    width, height = (int(v) for v in s.film().size())
    up = np.zeros(3)
    k = int(np.argmax(np.abs(axes[1])))
    up[k] = math.copysign(1.0, axes[1][k])
    x_fov = _value(params, "x_fov")
    return {"eye": m[:3, 3].tolist(), "axes": axes.tolist(), "up": up.tolist(),
            "c": 1.0 / math.tan(math.radians(x_fov) / 2), "aspect": width / height,
            "offset": [_value(params, "principal_point_offset_x"), _value(params, "principal_point_offset_y")],
            "near": float(s.near_clip()), "far": float(s.far_clip()), "width": width, "height": height,
            "mirrored": bool(np.linalg.det(axes) < 0), "sensor": SENSORS[kind], "x_fov": x_fov}


def project(camera, points):
    """(N, 2) film positions in [0, 1]^2 (x right, y down, as Mitsuba's ``sample_ray``
    takes them) of world ``points`` (N, 3) seen by ``camera`` (:func:`sensor_camera`),
    and their depths z along the view axis."""
    local = (np.asarray(points, np.float64) - camera["eye"]) @ np.asarray(camera["axes"]).T
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    ox, oy = camera["offset"]
    ndc_x = -camera["c"] * x / z - 2 * ox
    ndc_y = camera["aspect"] * camera["c"] * y / z + 2 * oy
    return np.stack([(ndc_x + 1) / 2, (1 - ndc_y) / 2], axis=1), z
