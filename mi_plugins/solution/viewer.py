"""The solution in a browser: one self-contained HTML file (WebGL 2, no network) showing a
solution's baked radiance from a walkthrough camera.

The page (``mi_plugins/data/viewer.html``, its script written here, no library) draws
the meshes of :func:`mi_plugins.solution.export.baked_shapes`: per-vertex radiance (side 0
on the side the patch normal points to, side 1 behind), interpolated over each triangle
(perspective-correct, linear), times 2^exposure, clipped to [0, 1] and encoded with the
sRGB curve, as the package's PNG writer and Mitsuba's 8-bit conversion do. What the
``baked`` display shows, the page shows, but for:

- visible points where the display gathers instead of reading the solution (surfaces
  that are not purely diffuse, among others; the page shows the vertex values there,
  emission only on surfaces that are not purely diffuse), mirrors and glass (the
  display follows them);
- textured emission (the page shows its fit at the vertices) and the analytic shapes'
  cells (two triangles each: linear where the display is bilinear, flat facets on
  spheres and cylinders);
- an environment emitter: a ``constant`` one is the background colour, any other is
  black (the overlay says so).

The emitting shapes are drawn after the others with a polygon offset of one pixel's
depth slope: a lamp lying a hair below a ceiling (the measured Cornell box's 0.1 mm)
would otherwise lose rows of pixels to it, where the rasteriser's sub-pixel snapping of
the vertices moves depths at grazing angles by more than the gap.

The geometry and the colours are inline: float32 positions, float16 radiance (float32
where a value exceeds 60000), 16- or 32-bit indices, compressed with zlib and base64
encoded; the page inflates them with the browser's ``DecompressionStream``. It starts
from the scene's sensor (:mod:`mi_plugins.solution.viewer_camera`), shows the film's aspect
(letterboxed) and sets its title to ``ready`` once drawn, or to ``error: ...``; the URL
hash ``#test`` hides the overlay.
"""
import base64
import html
import json
import math
import numbers
import os
import zlib

import numpy as np

TEMPLATE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data", "viewer.html")
#: valid initial exposures (stops)
EXPOSURE_RANGE = (-20.0, 20.0)
HALF_MAX = 60000.0


def _section(parts, layout, name, array, kind):
    offset = sum(len(p) for p in parts)
    data = np.ascontiguousarray(array).tobytes()
    parts.append(data + b"\0" * (-len(data) % 4))
    layout[name] = {"offset": offset, "count": int(np.asarray(array).size), "type": kind}


def _background(scene):
    """(RGB radiance or None, note or None) of the scene's environment."""
    import drjit as dr
    import mitsuba as mi
    env = scene.environment()
    if env is None:
        return None, None
    if env.class_name() != "ConstantBackgroundEmitter":
        return None, "the environment (%s) is not shown: black background" % env.class_name()
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(0, 0, -1)
    value = np.array(mi.Color3f(env.eval(si)), dtype=np.float64).ravel()
    return [float(v) for v in value[:3]], None


def page_data(solution, scene, sensor=0, exposure=0.0):
    """(the page's JSON-able description, its binary payload): camera, bounds, counts,
    notes and the layout of the payload (positions, front, back, indices)."""
    from mi_plugins.solution.surfaces import purely_diffuse
    from mi_plugins.solution.export import baked_shapes
    from mi_plugins.solution.viewer_camera import sensor_camera
    if not (isinstance(exposure, numbers.Real) and not isinstance(exposure, bool) and math.isfinite(exposure)
            and EXPOSURE_RANGE[0] <= exposure <= EXPOSURE_RANGE[1]):
        raise ValueError("Solution.to_html: exposure %r; valid range: %g .. %g (stops)"
                         % (exposure, EXPOSURE_RANGE[0], EXPOSURE_RANGE[1]))
    order = solution.check_scene(scene)       # the geometry and the camera must be the solution's scene's
    camera = sensor_camera(scene, sensor)
    shapes = baked_shapes(solution, "Solution.to_html")
    counts = np.array([len(s[1]) for s in shapes], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    positions = np.concatenate([s[1] for s in shapes]).astype(np.float32)
    # the emitting shapes' triangles last: the page draws them with a polygon offset
    emitting = np.array([scene.shapes()[order[k]].is_emitter() for k in range(len(shapes))], dtype=bool)
    ranks = np.argsort(emitting, kind="stable")
    faces = np.concatenate([shapes[k][2] + starts[k] for k in ranks])
    emitter_indices = 3 * int(sum(len(shapes[k][2]) for k in ranks if emitting[k]))
    front = np.concatenate([s[3] for s in shapes])
    back = np.concatenate([s[4] for s in shapes])
    color = np.float16 if max(np.abs(front).max(initial=0), np.abs(back).max(initial=0)) < HALF_MAX else np.float32
    parts, layout = [], {}
    _section(parts, layout, "positions", positions, "f32")
    _section(parts, layout, "front", front.astype(color), "f16" if color is np.float16 else "f32")
    if np.any(back != 0.0):
        _section(parts, layout, "back", back.astype(color), "f16" if color is np.float16 else "f32")
    small = len(positions) <= 65536
    _section(parts, layout, "indices", faces.astype(np.uint16 if small else np.uint32), "u16" if small else "u32")
    background, note = _background(scene)
    diffuse = [purely_diffuse(s.bsdf()) for s in scene.shapes()]
    notes = [note] if note else []
    if not all(diffuse):
        notes.append("%d of %d shapes are not purely diffuse: they show their emission only"
                     % (len(diffuse) - sum(diffuse), len(diffuse)))
    if camera["sensor"] == "thinlens":
        notes.append("the thin lens is shown as a pinhole (no depth of field)")
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    meta = solution.meta
    info = {"camera": camera, "bounds": [lo.tolist(), hi.tolist()], "layout": layout,
            "vertices": int(len(positions)), "triangles": int(len(faces)), "exposure": float(exposure),
            "emitter_indices": emitter_indices,
            "background": background, "notes": notes,
            "summary": "%s, seed %s: %d triangles, %d vertices" % (meta.get("integrator"), meta.get("seed"),
                                                                   len(faces), len(positions))}
    return info, b"".join(parts)


def render_page(info, payload, title="mi_plugins solution"):
    """The HTML text of the viewer for ``page_data``'s (info, payload)."""
    with open(TEMPLATE, encoding="utf-8") as f:
        page = f.read()
    info = dict(info, data=base64.b64encode(zlib.compress(payload, 9)).decode("ascii"))
    text = json.dumps(info, separators=(",", ":")).replace("<", "\\u003c")
    return page.replace("{{TITLE}}", html.escape(title)).replace("{{DATA}}", text)


def write_html(solution, path, scene, sensor=0, exposure=0.0, title=None):
    """Write the viewer of ``solution`` (its ``scene``, starting from sensor ``sensor``,
    at ``exposure`` stops) to ``path``; returns the path."""
    info, payload = page_data(solution, scene, sensor, exposure)
    page = render_page(info, payload, title or "mi_plugins: %s solution" % solution.meta.get("integrator"))
    folder = os.path.dirname(os.path.abspath(str(path)))
    os.makedirs(folder, exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        f.write(page)
    return path
