"""Values of textures over their uv domain: the range checks of texture-valued plugin
parameters (:meth:`mi_plugins.base.params.Params.texture`) and of rules between them."""
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


# ------------------------------------------------ values edited through mi.traverse
# An edit is re-read by the plugin's reader from the values "as given" (as_given,
# as_properties); an invalid edit is undone (snapshot, restore).
def _short(x):
    """The shortest decimal that gives float32 ``x`` back (0.6, not 0.6000000238)."""
    return float(str(np.float32(x)))


def _rgb(values):
    """Three channels as a user would give them: a float when all equal (NaN included)."""
    rgb = [_short(v) for v in values]
    return rgb[0] if len({repr(v) for v in rgb}) == 1 else rgb


def texture_constant(texture):
    """What a texture holds, as a user would give it: a float (the same value in every
    channel) or an RGB list for a texture that is the same everywhere (uniform, srgb,
    rgb); the texture itself otherwise."""
    if texture.is_spatially_varying():
        return texture
    return _rgb(np.array(texture.eval(dr.zeros(mi.SurfaceInteraction3f))).ravel()[:3])


def as_given(value):
    """A parameter value edited through ``mi.traverse``, as a user would give it to the
    plugin's reader (:class:`mi_plugins.base.params.Params`), so that an edit is checked, and
    refused, exactly as at load time, with messages such as ``exponent=-1.0``: textures
    via :func:`texture_constant`; a JIT ``Float`` of one entry: a float; a ``Color3f`` of
    one entry: an RGB list (a float if all equal); a ``Float`` of several entries (a
    table): a string of comma-separated numbers."""
    if isinstance(value, mi.Texture):
        return texture_constant(value)
    array = np.array(value, dtype=np.float64)
    if array.size == 1:
        return _short(array.ravel()[0])
    if array.shape == (3, 1):
        return _rgb(array.ravel())
    return ", ".join(repr(_short(v)) for v in array.ravel())


def snapshot(values):
    """Copies of exposed parameter values ({name: JIT value or texture}), to undo an
    invalid edit with :func:`restore`: JIT values share their (immutable) variables; a
    texture is kept as copies of its own scene parameters."""
    copy = lambda v: type(v)(v) if isinstance(v, dr.ArrayBase) else v
    return {name: {k: copy(v) for k, v in mi.traverse(value).items()} if isinstance(value, mi.Texture)
            else copy(value) for name, value in values.items()}


def restore(values, snap):
    """Writes a :func:`snapshot` back in place: the objects that ``mi.traverse`` lists
    stay the same (and show the restored values)."""
    for name, value in values.items():
        if isinstance(value, mi.Texture):
            params = mi.traverse(value)
            params.update(snap[name])
        else:
            mi.set_property(value, snap[name])


def as_properties(plugin, values):
    """``mi.Properties`` of ``plugin`` holding ``values`` ({name: value as given})."""
    props = mi.Properties(plugin)
    for name, value in values.items():
        props[name] = value
    return props
