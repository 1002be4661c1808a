"""AnalyticCase: a closed Mitsuba scene together with its exact radiance.

A case is a set of surfaces (Mitsuba shape dicts with their BSDF and emitter),
a camera inside the closed geometry, and the exact radiance. Constant-radiance
cases override :meth:`AnalyticCase.exact_constant`; spatially varying cases
override :meth:`AnalyticCase.exact_at`, which evaluates the exact radiance at
the first surface hit of camera rays, and :meth:`AnalyticCase.expected`
averages it over each pixel footprint (box pixel filter) with stratified
supersampling. Where the radiance has a closed-form derivative w.r.t. a named case
parameter, :meth:`AnalyticCase.add_derivative` declares it together with the scene
parameter that realises it, and :meth:`AnalyticCase.expected_derivative` returns the
exact derivative image (see :mod:`mi_plugins.verify.analytic.gradients`).
"""
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.verify import geometry as geo


def copy_dict(d):
    """Copy nested dicts/lists of a scene description; Mitsuba objects are shared."""
    if isinstance(d, dict):
        return {k: copy_dict(v) for k, v in d.items()}
    if isinstance(d, list):
        return [copy_dict(v) for v in d]
    return d


def rgb(value, name):
    """Validate a float or RGB triple; returns a float64 array of shape (3,)."""
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
    except (TypeError, ValueError):
        raise ValueError("%s=%r: must be a float or an RGB triple of floats" % (name, value)) from None
    if not np.all(np.isfinite(arr)):
        raise ValueError("%s=%r: must be finite" % (name, value))
    return arr


def require_range(value, name, lo=None, hi=None, lo_open=False, hi_open=False, what="valid range"):
    """Raise ValueError unless every channel of ``value`` lies in the given interval."""
    arr = rgb(value, name)
    bad = np.zeros(3, dtype=bool)
    if lo is not None:
        bad |= (arr <= lo) if lo_open else (arr < lo)
    if hi is not None:
        bad |= (arr >= hi) if hi_open else (arr > hi)
    if bad.any():
        interval = "%s%s, %s%s" % ("(" if lo_open else "[", "-inf" if lo is None else lo,
                                    "inf" if hi is None else hi, ")" if hi_open or hi is None else "]")
        raise ValueError("%s=%r is outside the %s %s" % (name, value, what, interval))
    return arr


def rgb_dict(value):
    arr = rgb(value, "value")
    return {"type": "rgb", "value": [float(v) for v in arr]}


def truncated_geometric(ratio, max_depth):
    """sum_{k < D} ratio^k for Mitsuba's max_depth D (-1 = infinite), per channel."""
    ratio = rgb(ratio, "ratio")
    if max_depth is None or max_depth < 0:
        return 1.0 / (1.0 - ratio)
    if max_depth == 0:
        return np.zeros(3)
    return np.array([sum(r ** k for k in range(max_depth)) for r in ratio])


def truncated_geometric_derivative(ratio, max_depth):
    """d/dratio of :func:`truncated_geometric`: sum_{k < D} k ratio^(k-1) (-1: 1 / (1 - ratio)^2)."""
    ratio = rgb(ratio, "ratio")
    if max_depth is None or max_depth < 0:
        return 1.0 / (1.0 - ratio) ** 2
    return np.array([sum(k * r ** (k - 1) for k in range(1, max_depth)) for r in ratio])


@dataclass
class Derivative:
    """The closed-form derivative of a case's radiance w.r.t. one named case parameter.

    ``key``: the scene parameter that realises it, relative to each surface: on every
    surface ``<surface id>.<key>`` (or ``<surface id>.<key>.value``, a texture's value) of
    ``mi.traverse(scene)``, all moved together. ``constant(max_depth)``: the RGB derivative
    where it is the same everywhere, else ``at(si, ray, max_depth, scene)``: Color3f at the
    first hit of camera rays. ``bias``: a known bounded absolute bias of the closed form in
    this scene (0: exact). ``formula``: one line for reports.
    """
    key: str
    constant: object = None
    at: object = None
    bias: float = 0.0
    formula: str = ""


class AnalyticCase:
    """A closed scene with known exact radiance.

    Parameters: ``name`` (str), ``surfaces`` ({id: Mitsuba shape dict with
    'bsdf' and 'emitter'}), ``camera`` ((origin, target, up)), ``resolution``
    (film width = height, pixels), ``fov`` (degrees), ``params`` (the factory
    arguments, for reports), ``description`` (one line: what is exact).
    """

    #: stratified points per pixel side used by expected() where the radiance varies
    supersampling = 12
    #: a known, bounded absolute bias of the stated value (0: exact); the matrix passes it
    #: to check() explicitly as ``bias=``
    known_bias = 0.0

    def __init__(self, name, surfaces, camera, resolution=32, fov=60.0, params=None, description=""):
        if int(resolution) < 1:
            raise ValueError("resolution=%r: must be a positive integer" % (resolution,))
        self.name = name
        self.surfaces = surfaces
        self.camera = camera
        self.resolution = int(resolution)
        self.fov = float(fov)
        self.params = dict(params or {})
        self.description = description
        #: {parameter name: Derivative}: the closed-form derivatives (add_derivative)
        self.derivatives = {}

    # ------------------------------------------------------------------ scene
    def sensor_dict(self, sampler=None):
        origin, target, up = self.camera
        sensor = {
            "type": "perspective",
            "fov": self.fov,
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up),
            "film": {"type": "hdrfilm", "width": self.resolution, "height": self.resolution,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb", "component_format": "float32"},
            "sampler": dict(sampler) if sampler else {"type": "independent"},
        }
        return sensor

    def scene_dict(self, integrator=None, sampler=None):
        """Mitsuba scene dict with the given integrator (dict or plugin name) and sampler dict."""
        d = {"type": "scene", "sensor": self.sensor_dict(sampler)}
        if integrator is not None:
            d["integrator"] = {"type": integrator} if isinstance(integrator, str) else dict(integrator)
        for key, shape in self.surfaces.items():
            d[key] = copy_dict(shape)
        return d

    def scene(self, integrator=None, sampler=None):
        """Load the case as a mi.Scene (default integrator: Mitsuba's ``path``)."""
        # optimize=False: Mitsuba 3.9's load_dict merges identical plugin dicts, which would
        # attach one Python emitter instance to several shapes (an error).
        return mi.load_dict(self.scene_dict(integrator or {"type": "path"}, sampler), optimize=False)

    # ------------------------------------------------------------------ exact values
    def exact_constant(self, max_depth=-1):
        """The exact radiance as an RGB array when it is the same everywhere, else None."""
        return None

    def exact_at(self, si, ray, max_depth, scene):
        """Exact radiance (mi.Color3f) leaving the first hit ``si`` of ``scene`` towards the camera."""
        raise NotImplementedError

    def expected(self, max_depth=-1, supersampling=None):
        """Exact per-pixel radiance, numpy (H, W, 3): the average of the exact radiance over
        each pixel footprint (box filter), stratified ``supersampling``^2 points per pixel."""
        const = self.exact_constant(max_depth)
        if const is not None:
            return np.broadcast_to(const, (self.resolution, self.resolution, 3)).astype(np.float64)
        return self._supersampled(max_depth, int(supersampling or self.supersampling))

    def expected_mean(self, max_depth=-1):
        return float(np.mean(self.expected(max_depth)))

    # ------------------------------------------------------------------ exact derivatives
    def add_derivative(self, name, key, constant=None, at=None, bias=0.0, formula=""):
        """Declare the closed-form derivative w.r.t. parameter ``name`` (see :class:`Derivative`)."""
        if (constant is None) == (at is None):
            raise ValueError("add_derivative(%r): give exactly one of constant= and at=" % (name,))
        self.derivatives[name] = Derivative(key, constant, at, float(bias), formula)
        return self

    def derivative(self, name):
        """The :class:`Derivative` named ``name``; ValueError naming the valid names otherwise."""
        if name not in self.derivatives:
            valid = ", ".join(sorted(self.derivatives)) or "none (no derivative of this case has a closed form)"
            raise ValueError("%s: name=%r has no closed-form derivative; valid names: %s" % (self.name, name, valid))
        return self.derivatives[name]

    def expected_derivative(self, name, max_depth=-1, supersampling=None):
        """Exact per-pixel derivative of the radiance w.r.t. parameter ``name`` moved together
        on every surface, numpy (H, W, 3), averaged over pixel footprints like :meth:`expected`."""
        spec = self.derivative(name)
        if spec.constant is not None:
            value = rgb(spec.constant(max_depth), "derivative %r" % name)
            return np.broadcast_to(value, (self.resolution, self.resolution, 3)).astype(np.float64)
        return self._supersampled(max_depth, int(supersampling or self.supersampling), spec.at)

    def derivative_keys(self, name, params):
        """The keys of ``params`` (``mi.traverse`` of this case's scene) that realise ``name``:
        one per surface. ValueError naming the missing keys where the plugins do not list them."""
        key = self.derivative(name).key
        keys, missing = [], []
        for surface in self.surfaces:
            found = [k for k in ("%s.%s" % (surface, key), "%s.%s.value" % (surface, key)) if k in params]
            (keys if found else missing).append(found[0] if found else "%s.%s" % (surface, key))
        if missing:
            raise ValueError("%s: parameter %r is realised by the scene parameter(s) %s, which mi.traverse(scene) "
                             "does not list (the plugin does not expose it for differentiation)"
                             % (self.name, name, ", ".join(missing)))
        return keys

    def _supersampled(self, max_depth, k, exact_at=None):
        scene = self.scene({"type": "path"})
        sensor = scene.sensors()[0]
        res = self.resolution
        n = res * res * k * k
        idx = dr.arange(mi.UInt32, n)
        pixel = idx // (k * k)
        sub = idx % (k * k)
        px = mi.Float(pixel % res) + (mi.Float(sub % k) + 0.5) / k
        py = mi.Float(pixel // res) + (mi.Float(sub // k) + 0.5) / k
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(px / res, py / res), mi.Point2f(0.5, 0.5))
        si = scene.ray_intersect(ray)
        value = (exact_at or self.exact_at)(si, ray, max_depth, scene)
        value = dr.select(si.is_valid(), value, dr.nan)  # an open case would show as NaN
        acc = dr.zeros(mi.Color3f, res * res)
        dr.scatter_reduce(dr.ReduceOp.Add, acc, value / (k * k), pixel)
        img = np.array(acc, dtype=np.float64).T.reshape(res, res, 3)  # Color3f -> (3, N)
        if not np.all(np.isfinite(img)):
            raise RuntimeError("%s: camera rays escape the scene; the case is not closed" % self.name)
        return img

    # ------------------------------------------------------------------ applicability
    def not_applicable(self, integrator):
        """Reason why ``integrator`` (dict) cannot handle this case by design, or None."""
        return None

    def __repr__(self):
        const = self.exact_constant(-1)
        exact = ("L = %s" % np.array2string(const, precision=4)) if const is not None else "spatially varying L"
        return "AnalyticCase(%s, %s, %dx%d; %s)" % (self.name, exact, self.resolution, self.resolution,
                                                     self.description)


def camera_for(geometry, radius=1.0):
    """A camera inside the closed geometry looking at something non-trivial."""
    if geometry in ("sphere", "sphere_mesh"):
        r = float(radius)
        return ([0.3 * r, 0.2 * r, 0.4 * r], [-0.5 * r, -0.1 * r, -1.0 * r], [0, 1, 0])
    if geometry == "box":
        return ([0.4, 0.3, 0.8], [-0.6, -0.4, -1.0], [0, 1, 0])
    if geometry == "sierpinski":
        return ([0.55, 0.45, 0.9], [0.0, -0.2, 0.0], [0, 1, 0])
    raise ValueError("geometry=%r: must be one of %s" % (geometry, ", ".join(geo.GEOMETRIES)))


def closed_surfaces(geometry, bsdf, emitter, **geometry_options):
    """Every surface of ``geometry`` with (deep copies of) the same BSDF and emitter dicts."""
    shapes = geo.surfaces(geometry, **geometry_options)
    for shape in shapes.values():
        shape["bsdf"] = copy_dict(bsdf)
        if emitter is not None:
            shape["emitter"] = copy_dict(emitter)
    return shapes
