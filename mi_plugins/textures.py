"""Reading texture-valued plugin parameters (float, RGB or any Mitsuba texture)."""
import drjit as dr
import mitsuba as mi
import numpy as np


def texture_param(props, name, default, plugin):
    """Return a mi.Texture for parameter ``name`` (floats become uniform textures)."""
    if name not in props:
        value = default
    else:
        value = props.get(name)
    if isinstance(value, mi.Texture):
        return value
    try:
        v = float(value)
        return mi.load_dict({"type": "uniform", "value": v})
    except TypeError:
        pass
    try:
        rgb = [float(c) for c in value]
        return mi.load_dict({"type": "srgb", "color": rgb, "unbounded": True})
    except TypeError:
        raise ValueError("%s: parameter '%s'=%r must be a float, an RGB value or a texture" % (plugin, name, value))


def _grid_values(texture, n=256):
    si = dr.zeros(mi.SurfaceInteraction3f, n * n)
    i = dr.arange(mi.UInt32, n * n)
    si.uv = mi.Point2f((mi.Float(i % n) + 0.5) / n, (mi.Float(i // n) + 0.5) / n)
    return texture.eval(si)


def texture_max(texture):
    """Largest value (over channels and the uv domain) of a texture, as a float."""
    try:
        return float(texture.max())
    except Exception:  # e.g. bitmaps: no closed-form max; scan the uv domain
        return float(np.max(np.array(_grid_values(texture))))


def texture_min(texture):
    """Smallest value (over channels and the uv domain) of a texture, as a float."""
    return float(np.min(np.array(_grid_values(texture))))


def texture_sum_max(*textures):
    """Largest value (over channels and the uv domain) of the sum of several textures."""
    total = None
    for texture in textures:
        values = np.array(_grid_values(texture))
        total = values if total is None else total + values
    return float(np.max(total))
