"""The one reader of plugin parameters: every plugin of the package reads its
``mi.Properties`` through :class:`Params`, and every invalid value (or combination of
values) raises :class:`ParameterError` with one message format::

    ray_bundle: parameter chains=0 is invalid; valid range: an integer >= 1
    ray_bundle: parameter bidirectional='false' is invalid; valid range: a boolean (true or false: ...)
    phong: parameters diffuse_reflectance=0.7, specular_reflectance=0.5 are invalid together;
        valid range: diffuse_reflectance + specular_reflectance <= 1 in every channel (reaches 1.2)

(plugin, parameter(s) with the value given, or the default, the valid range). Usage::

    p = Params(props, "ray_bundle")
    self.chains = p.int("chains", 1, lo=1)
    self.first_shot = p.bool("first_shot", False)
    if burn_in >= iterations:
        raise p.conflict(("burn_in", "iterations"), "burn_in in 0 .. iterations - 1")

How values arrive (Mitsuba 3.9.1): ``mi.load_dict`` keeps Python ``bool``, ``int``
and ``float`` (an integer too large for 64 bits becomes a float), strings, 3-lists/
tuples/numpy arrays as ``Array3f64`` vectors, ``{'type': 'rgb', ...}`` and
``mi.ScalarColor3f`` as ``ScalarColor3d``, nested plugin dicts and ``{'type': 'ref'}``
as the instantiated objects. XML ``<boolean>``, ``<integer>``, ``<float>``,
``<string>``, ``<rgb>``, nested ``<texture>``/``<emitter>`` and ``<ref>`` give the
same Python types (XML's own parser already refuses e.g. ``<boolean value="abc"/>``
or ``<integer value="2.5"/>``, before any plugin sees them). Only names that a plugin
asks for are queried (``props.get``): Mitsuba's error for unreferenced properties
(a misspelt parameter name) keeps working.

Strictness, as in Mitsuba's own C++ plugins: an integer parameter takes only an
integer (not a bool, a float or a string), a boolean only a real boolean (never a
string such as 'false' or an integer), a number (float) an integer or a float that is
finite; strings are not converted.
"""
import math

import numpy as np
import mitsuba as mi

from mi_plugins.base.textures import texture_range

_builtin_int, _builtin_float, _builtin_bool = int, float, bool

#: shown instead of a value for a parameter that was not given (and has no default)
NOT_GIVEN = "(not given)"


class ParameterError(ValueError):
    """An invalid plugin parameter, or an invalid combination of parameters.

    ``plugin``: the plugin name; ``names``: the parameter names; ``values``: the values
    (as given, or the defaults used); ``valid``: the valid range in words."""

    def __init__(self, plugin, items, valid):
        self.plugin, self.valid = plugin, valid
        self.names = tuple(name for name, _ in items)
        self.values = tuple(value for _, value in items)
        super().__init__(message(plugin, items, valid))


def show(value, name=None):
    """A short text of a parameter value for messages (repr for numbers and strings;
    objects by their kind and id, unless the id is just the parameter ``name``)."""
    if value is NOT_GIVEN or value is None:
        return NOT_GIVEN
    if isinstance(value, (_builtin_bool, _builtin_int, _builtin_float, str)):
        text = repr(value)
    elif _is_triple(value):
        try:
            text = "[%s]" % ", ".join(repr(_builtin_float(v)) for v in value)
        except (TypeError, ValueError):
            text = repr(value)
    elif isinstance(value, mi.Object):
        kind = str(value).split("\n", 1)[0].split("[", 1)[0].strip() or type(value).__name__
        ident = value.id() if hasattr(value, "id") else ""
        text = "<%s id=%r>" % (kind, ident) if ident and ident != name and not ident.startswith("_unnamed") \
            else "<%s>" % kind
    else:
        text = "<%s %s>" % (type(value).__name__, str(value).split("\n", 1)[0])
    return text if len(text) <= 80 else text[:77] + "..."


def message(plugin, items, valid):
    """The message format of every :class:`ParameterError`."""
    assignments = ", ".join("%s=%s" % (name, show(value, name)) for name, value in items)
    if len(items) == 1:
        return "%s: parameter %s is invalid; valid range: %s" % (plugin, assignments, valid)
    return "%s: parameters %s are invalid together; valid range: %s" % (plugin, assignments, valid)


def parameter_error(plugin, items, valid):
    """A :class:`ParameterError` for checks made outside a constructor (e.g. when a
    scene is rendered): ``items`` is a list of (name, value)."""
    return ParameterError(plugin, list(items), valid)


def _is_triple(value):
    """A sequence of values (Dr.Jit scalar arrays such as ScalarColor3d/Array3f64, lists,
    tuples, numpy arrays), not a string or a Mitsuba object."""
    return (not isinstance(value, (str, bytes, dict, mi.Object)) and hasattr(value, "__len__")
            and hasattr(value, "__getitem__"))


def _is_number(value):
    return isinstance(value, (_builtin_int, _builtin_float)) and not isinstance(value, _builtin_bool)


def _fmt(x):
    if isinstance(x, _builtin_int):
        return str(x)
    return repr(x) if not x.is_integer() else "%g" % x


def _interval(lo, hi, lo_open=False, hi_open=False):
    """Words for the range of a number: '>= 0', '> 0', 'in [0, 1]', '' (any)."""
    if lo is not None and hi is not None:
        return "in %s%s, %s%s" % ("(" if lo_open else "[", _fmt(lo), _fmt(hi), ")" if hi_open else "]")
    if lo is not None:
        return "%s %s" % (">" if lo_open else ">=", _fmt(lo))
    if hi is not None:
        return "%s %s" % ("<" if hi_open else "<=", _fmt(hi))
    return ""


def _outside(x, lo, hi, lo_open=False, hi_open=False):
    return ((lo is not None and (x <= lo if lo_open else x < lo))
            or (hi is not None and (x >= hi if hi_open else x > hi)))


class Params:
    """Reads the parameters of one plugin instance from ``props`` (``mi.Properties``).

    Every reader takes the parameter ``name`` and its ``default`` (used when the
    parameter is not given; ``required=True`` instead makes a missing parameter an
    error) and returns the value, or raises :class:`ParameterError`. ``given(name)``
    tells whether a parameter was given; :meth:`conflict` and :meth:`error` build the
    errors of rules the plugin checks itself."""

    def __init__(self, props, plugin):
        self.props, self.plugin = props, plugin
        self._values = {}     # name -> value given, or the default used

    # ------------------------------------------------------------------ basics
    def _fetch(self, name, default, required, valid):
        """(value, given) of ``name``; a missing required parameter is an error."""
        if name in self.props:
            value = self.props.get(name)
            self._values[name] = value
            return value, True
        if required:
            self._values[name] = NOT_GIVEN
            raise self.error(name, valid + " (required)")
        self._values[name] = default
        return default, False

    def given(self, name):
        """Was ``name`` given (as opposed to absent)?"""
        return name in self.props

    def value(self, name):
        """The value of ``name`` as given, or its default once read."""
        return self._values.get(name, self.props.get(name) if name in self.props else NOT_GIVEN)

    def error(self, name, valid, value=None):
        """A ParameterError for parameter ``name`` (its value as read, unless ``value``)."""
        return ParameterError(self.plugin, [(name, self.value(name) if value is None else value)], valid)

    def conflict(self, names, valid):
        """A ParameterError for a rule between several parameters (all named, with their
        values as given or their defaults)."""
        return ParameterError(self.plugin, [(name, self.value(name)) for name in names], valid)

    # ------------------------------------------------------------------ readers
    def int(self, name, default=None, lo=None, hi=None, required=False, note=None):
        """An integer (Python int, XML <integer>) in [lo, hi]."""
        rng = "an integer"
        if lo is not None and hi is not None:
            rng += " in %d .. %d" % (lo, hi)
        elif lo is not None or hi is not None:
            rng += " " + _interval(lo, hi)
        valid = rng + (" (%s)" % note if note else "")
        value, given = self._fetch(name, default, required, valid)
        if not given:
            return value
        if not isinstance(value, _builtin_int) or isinstance(value, _builtin_bool) or _outside(value, lo, hi):
            raise self.error(name, valid)
        return _builtin_int(value)

    def float(self, name, default=None, lo=None, hi=None, lo_open=False, hi_open=False, required=False, note=None):
        """A finite number (Python int or float, XML <float> or <integer>) in the range
        given by ``lo``/``hi`` (closed unless ``lo_open``/``hi_open``). ``default=None``
        without ``required``: an optional parameter (None when absent)."""
        rng = _interval(lo, hi, lo_open, hi_open)
        valid = "a finite number" + (" " + rng if rng else "") + (" (%s)" % note if note else "")
        value, given = self._fetch(name, default, required, valid)
        if not given:
            return value
        if not _is_number(value) or not math.isfinite(value) or _outside(value, lo, hi, lo_open, hi_open):
            raise self.error(name, valid)
        return _builtin_float(value)

    def bool(self, name, default):
        """A boolean: Python True/False or XML <boolean>; never a string or a number."""
        valid = "a boolean (true or false: Python bool, XML <boolean>; not a string or a number)"
        value, given = self._fetch(name, default, False, valid)
        if given and not isinstance(value, _builtin_bool):
            raise self.error(name, valid)
        return value

    def choice(self, name, default, choices):
        """One of the strings ``choices``."""
        valid = "one of %s" % ", ".join(repr(c) for c in choices)
        value, given = self._fetch(name, default, False, valid)
        if given and (not isinstance(value, str) or value not in choices):
            raise self.error(name, valid)
        return value

    def rgb(self, name, default=None, lo=None, hi=None, lo_open=False, hi_open=False, required=False):
        """A float or an RGB triple (3-list/tuple, {'type': 'rgb'}, mi.ScalarColor3f,
        XML <float>/<rgb>), finite and in range in every channel: numpy float64 (3,)."""
        rng = _interval(lo, hi, lo_open, hi_open)
        valid = "a float or an RGB triple, finite%s in every channel" % (" and " + rng if rng else "")
        value, given = self._fetch(name, default, required, valid)
        if value is None:
            return None
        rgb = _as_rgb(value)
        if rgb is None or not np.all(np.isfinite(rgb)) or any(_outside(x, lo, hi, lo_open, hi_open) for x in rgb):
            raise self.error(name, valid)
        return rgb

    def texture(self, name, default, lo=None, hi=None):
        """A float, an RGB triple or a texture (nested <texture> / plugin dict), finite
        and in [lo, hi] everywhere (textures: checked on a 256 x 256 uv grid unless they
        report their maximum): mi.Texture (floats: 'uniform', RGB: unbounded 'srgb')."""
        rng = _interval(lo, hi)
        valid = "a float, an RGB triple or a texture, finite%s everywhere" % (" and " + rng if rng else "")
        value, given = self._fetch(name, default, False, valid)
        if isinstance(value, mi.Texture):
            low, high, finite = texture_range(value)
            if not finite or _outside(low, lo, None) or _outside(high, None, hi):
                raise self.error(name, valid + " (the texture reaches [%.6g, %.6g])" % (low, high))
            return value
        rgb = _as_rgb(value)
        if rgb is None or not np.all(np.isfinite(rgb)) or any(_outside(x, lo, hi) for x in rgb):
            raise self.error(name, valid)
        if _is_number(value):
            return mi.load_dict({"type": "uniform", "value": _builtin_float(value)})
        return mi.load_dict({"type": "srgb", "color": [_builtin_float(c) for c in rgb], "unbounded": True})

    def reference(self, name, kind, what, required=False):
        """An object of class ``kind`` (a class or tuple), given by reference (XML <ref>,
        ``{'type': 'ref', 'id': ...}``), nested or as the object itself; ``what`` names it
        for the message. None when absent and not required."""
        valid = what
        value, given = self._fetch(name, None, required, valid)
        if given and not isinstance(value, kind):
            raise self.error(name, valid)
        return value

    def floats(self, name, default=None, lo=None, hi=None, min_count=1, required=False):
        """A list of finite numbers in [lo, hi]: a string of comma- or space-separated
        numbers (XML <string>), or a 3-list/RGB in a dict: numpy float64 array."""
        rng = _interval(lo, hi)
        valid = "a string of at least %d comma-separated finite numbers%s" % (min_count, " " + rng if rng else "")
        value, given = self._fetch(name, default, required, valid)
        if value is None:
            return None
        if isinstance(value, str):
            items = [v for v in value.replace(",", " ").split() if v]
        elif _is_triple(value):
            items = list(value)
        else:
            raise self.error(name, valid)
        try:
            values = np.array([_builtin_float(v) for v in items], dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(name, valid) from None
        if len(values) < min_count or not np.all(np.isfinite(values)) or any(_outside(x, lo, hi) for x in values):
            raise self.error(name, valid)
        return values


def _as_rgb(value):
    """numpy (3,) float64 of a number or an RGB triple; None for anything else."""
    if _is_number(value):
        return np.full(3, _builtin_float(value))
    if _is_triple(value):
        try:
            rgb = np.array([_builtin_float(v) for v in value], dtype=np.float64)
        except (TypeError, ValueError):
            return None
        return rgb if rgb.shape == (3,) else None
    return None
