"""Values of textures over their uv domain: the range checks of texture-valued plugin
parameters (:meth:`mi_plugins.params.Params.texture`) and of rules between them."""
import drjit as dr
import mitsuba as mi
import numpy as np


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


def texture_range(texture):
    """(smallest value, largest value, all values finite) of a texture over channels and
    the uv domain (one scan of the uv grid; the largest value also from ``max()``)."""
    values = np.array(_grid_values(texture))
    finite = bool(np.all(np.isfinite(values)))
    return float(np.min(values)), max(float(np.max(values)), texture_max(texture)), finite


def texture_sum_max(*textures):
    """Largest value (over channels and the uv domain) of the sum of several textures."""
    total = None
    for texture in textures:
        values = np.array(_grid_values(texture))
        total = values if total is None else total + values
    return float(np.max(total))
