"""``directional_area``: an area light with direction-dependent emission.

    Le(x, w) = radiance(x) * profile(cos theta),

theta being the angle between w and the surface normal. Used to test non-diffuse
light sources (the analytic-scenes paper, sections 2.2 and 3.2).

The user reference (parameters, examples) is the class docstring.

Emission directions for light tracing are importance sampled with density
proportional to profile * cos (exactly for 'cosine_power', via a fine piecewise-
linear table for 'tabulated'; weights use the density actually sampled, so both are
unbiased). :meth:`hemispherical_integral` returns the exact integral of
profile * cos over the hemisphere, :meth:`total_power` the exact emitted power
(radiance must be uniform; for textures it is estimated numerically).

Scene parameters: ``traverse`` exposes the radiance texture and the profile's
``exponent`` or table ``values`` (``mi.Float``, opaque in kernels); after an edit,
``parameters_changed`` re-reads them with the load-time reader and recomputes the
integral, the sampling table and the checks of a ``separable`` BSDF on the same shape.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.emitters.surface_emitter import SurfaceEmitter
from mi_plugins.light.direct import (IsotropicLobe,
    square_to_power_cosine_hemisphere,
    square_to_power_cosine_hemisphere_pdf)
from mi_plugins.base.params import NOT_GIVEN, Params, parameter_error

PROFILES = ("cosine_power", "tabulated")


def tabulated_integral_weights(k):
    """Weights w of the exact integral 2 pi * integral_0^{pi/2} p(theta) cos(theta) sin(theta)
    dtheta = w . values for p piecewise linear in theta on a uniform grid of ``k`` values
    (numpy float64; the integral is linear in the values)."""
    t = np.linspace(0.0, np.pi / 2, k)
    t0, t1, h = t[:-1], t[1:], t[1] - t[0]
    # on a segment, p = a + b t with a = p0 (1 + t0/h) - p1 t0/h, b = (p1 - p0)/h, and
    # integral of (a + b t) cos(t) sin(t) dt = a [-cos(2t)/4] + b [-t cos(2t)/4 + sin(2t)/8]
    dc = (np.cos(2 * t0) - np.cos(2 * t1)) / 4
    prim = lambda x: -x * np.cos(2 * x) / 4 + np.sin(2 * x) / 8
    dd = prim(t1) - prim(t0)
    w = np.zeros(k)
    w[:-1] += (1 + t0 / h) * dc - dd / h
    w[1:] += -t0 / h * dc + dd / h
    return 2 * np.pi * w


def tabulated_hemispherical_integral(values):
    """Exact 2 pi * integral_0^{pi/2} p(theta) cos(theta) sin(theta) dtheta for p piecewise
    linear in theta on a uniform grid."""
    return float(tabulated_integral_weights(len(values)) @ np.asarray(values, dtype=np.float64))


class DirectionalAreaEmitter(SurfaceEmitter):
    r"""
    .. _emitter-directional_area:

    ``directional_area`` (area light with direction-dependent emission)
    --------------------------------------------------------------------

    Le(x, w) = radiance(x) profile(cos theta), theta measured from the surface normal;
    the non-diffuse light source of the analytic-scenes paper (sections 2.2 and 3.2).

    .. pluginparameters::

     * - radiance
       - float, RGB or texture
       - 1.0
       - >= 0, spatial factor; exposed, differentiable
     * - profile
       - string
       - ``'cosine_power'``
       - ``'cosine_power'`` or ``'tabulated'``
     * - exponent
       - float
       - 1.0
       - n >= 0 of cos^n (0 = diffuse); only with ``'cosine_power'``; exposed, differentiable
     * - values
       - string of floats
       - required for ``'tabulated'``
       - >= 2 values >= 0, not all 0: profile at theta uniformly spaced over [0, pi/2],
         linear in theta; only with ``'tabulated'``; exposed (a ``mi.Float`` table), differentiable

    Emission directions are importance sampled proportionally to profile x cos (exact
    for cos^n, a 2048-bin piecewise-linear table otherwise; chi-square tested).
    ``emitter.hemispherical_integral()`` is the exact integral of profile x cos,
    ``emitter.total_power()`` the exact power (uniform radiance; textures: numeric).

    Exposed parameters (``mi.traverse``): ``radiance.value`` (or the keys of a texture),
    ``exponent`` or ``values``; an edit is checked like a value at load (and against the
    ``separable`` BSDF of the shape), the integral and the sampling tables are recomputed;
    an invalid edit raises and is undone.

    .. code-block:: python

        'emitter': {'type': 'directional_area', 'profile': 'tabulated', 'values': '0.2, 1.2, 1.8, 0.4',
                    'radiance': {'type': 'rgb', 'value': [0.6, 0.9, 1.0]}}

    .. code-block:: xml

        <emitter type="directional_area"><string name="profile" value="cosine_power"/>
            <float name="exponent" value="4"/><rgb name="radiance" value="0.8, 0.5, 0.3"/></emitter>
    """


    def __init__(self, props):
        super().__init__(props)
        p = Params(props, self.plugin)
        self.profile = p.choice("profile", "cosine_power", PROFILES)
        self.radiance_texture, self.exponent, self.values = self._read(p)
        if self.profile == "cosine_power":
            self.m_exponent = mi.Float(self.exponent)
        else:
            self.m_table = mi.Float(self.values)
        self._derive()
        self._keep_valid()

    # ----------------------------------------------------------- parameters
    def _read(self, p):
        """(radiance, exponent, values), read and checked by ``p``: at load and after every
        edit (the profile itself is fixed at load)."""
        radiance = p.texture("radiance", 1.0, lo=0)
        exponent = p.float("exponent", 1.0, lo=0)
        values = p.floats("values", lo=0, min_count=2)
        if self.profile == "cosine_power":
            if values is not None:
                raise p.conflict(("values", "profile"), "'values' only with profile='tabulated'")
            return radiance, exponent, None
        if p.given("exponent"):
            raise p.conflict(("exponent", "profile"), "'exponent' only with profile='cosine_power'")
        if values is None:
            raise p.conflict(("values", "profile"), "profile='tabulated' needs 'values' (at least 2 profile "
                             "samples >= 0 over theta in [0, pi/2], e.g. '1, 0.5, 0')")
        if not np.any(values > 0):
            raise p.error("values", "a string of at least 2 comma-separated finite numbers >= 0, not all 0 "
                                    "(these values emit nothing)")
        return radiance, None, values

    def _derive(self):
        """Everything that depends on the parameters (one place for load and update): the
        kernels' opaque values, the integral of profile * cos (float64 and a differentiable
        ``mi.Float``), the importance-sampling table of a tabulated profile."""
        if self.profile == "cosine_power":
            dr.make_opaque(self.m_exponent)
            self._integral64 = 2 * np.pi / (self.exponent + 2)
            self._integral = dr.two_pi / (self.m_exponent + 2)
        else:
            dr.make_opaque(self.m_table)
            weights = tabulated_integral_weights(len(self.values))
            self._integral64 = float(weights @ self.values)
            self._integral = dr.sum(mi.Float(weights) * self.m_table)
            # importance sampling proportional to profile * cos, tabulated in theta
            self._lobe = IsotropicLobe(self.profile_at_theta)
        dr.make_opaque(self._integral)

    def traverse(self, callback):
        super().traverse(callback)
        callback.put("radiance", self.radiance_texture, mi.ParamFlags.Differentiable)
        # the profile shapes the emission lobe: flagged like a microfacet roughness in Mitsuba
        lobe = mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous
        if self.profile == "cosine_power":
            callback.put("exponent", self.m_exponent, lobe)
        else:
            callback.put("values", self.m_table, lobe)

    def _exposed(self):
        exposed = {"radiance": self.radiance_texture}
        if self.profile == "cosine_power":
            exposed["exponent"] = self.m_exponent
        else:
            exposed["values"] = self.m_table
        return exposed

    def _apply(self, p, keys):
        _, exponent, values = self._read(p)     # the edited texture object stays in place
        if self.profile == "cosine_power":
            self.exponent = exponent
        elif not keys or "values" in keys:
            self.values = values
        self._derive()

    def _notify(self):
        """A ``separable`` BSDF on this shape depends on the emission: it re-checks its rule
        and recomputes its sampling table (its own error, if any, is raised here)."""
        shape = self.get_shape()
        if shape is not None and getattr(shape.bsdf(), "emission", None) is self:
            shape.bsdf().emission_changed()

    # ----------------------------------------------------------- the profile
    def profile_value(self, cos_theta):
        """profile(cos theta) (Float)."""
        if self.profile == "cosine_power":
            return dr.power(dr.maximum(cos_theta, 0.0), self.m_exponent)
        theta = dr.acos(dr.clip(cos_theta, 0.0, 1.0))
        pos = theta / (dr.pi / 2) * (len(self.values) - 1)
        i = mi.UInt32(dr.minimum(dr.floor(pos), len(self.values) - 2))
        f = pos - mi.Float(i)
        v0 = dr.gather(mi.Float, self.m_table, i)
        v1 = dr.gather(mi.Float, self.m_table, i + 1)
        return dr.fma(f, v1 - v0, v0)

    def profile_at_theta(self, theta):
        """profile at polar angles ``theta`` (numpy, for tabulating densities)."""
        theta = np.asarray(theta, dtype=np.float64)
        if self.profile == "cosine_power":
            return np.power(np.maximum(np.cos(theta), 0.0), self.exponent)
        return np.interp(theta, np.linspace(0.0, np.pi / 2, len(self.values)), self.values)

    def hemispherical_integral(self):
        """Exact integral of profile(cos theta) cos(theta) over the hemisphere (float64)."""
        return self._integral64

    def hemispherical_integral_ad(self):
        """The same integral as the kernels use it: an opaque ``mi.Float``, differentiable
        with respect to the exponent or the table values."""
        return self._integral

    def total_power(self, samples=1 << 20):
        """Emitted power (RGB numpy): exact for uniform radiance, else estimated with
        ``samples`` area-uniform positions."""
        shape = self._shape()
        area = shape.surface_area()
        area = float(area[0]) if hasattr(area, "__len__") else float(area)
        if not self.radiance_texture.is_spatially_varying():
            si = dr.zeros(mi.SurfaceInteraction3f)
            mean = np.array(self.radiance_texture.eval(si)).ravel()[:3]
        else:
            rng = np.random.default_rng(0)
            ps = shape.sample_position(0.0, mi.Point2f(rng.random(samples), rng.random(samples)))
            si = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))
            mean = np.array(self.radiance_texture.eval(si)).reshape(3, -1).mean(axis=1)
        return mean * area * self.hemispherical_integral()

    def _check_separable_partner(self):
        """A ``separable`` BSDF on this emitter's shape must reference THIS emitter
        (otherwise it would silently assume another emission, e.g. none)."""
        if getattr(self, "_partner_checked", False):
            return
        shape = self._shape()
        bsdf = shape.bsdf()
        if hasattr(bsdf, "emission") and hasattr(bsdf, "normalization") and bsdf.emission is not self:
            raise parameter_error("separable", [("emission", NOT_GIVEN if bsdf.emission is None else bsdf.emission)],
                                  "a reference to this emitter: shape '%s' carries a 'directional_area' emitter and a "
                                  "'separable' BSDF whose 'emission' does not reference this emitter (%s); add "
                                  "<ref name=\"emission\" id=\"...\"/> to its emitter"
                                  % (shape.id(), "it has no emission" if bsdf.emission is None else
                                     "it references another emitter"))
        self._partner_checked = True

    # ----------------------------------------------------------- SurfaceEmitter interface
    def radiance(self, si, wo, active):
        self._check_separable_partner()
        return self.radiance_texture.eval(si, active) * self.profile_value(mi.Frame3f.cos_theta(wo))

    def sample_outgoing(self, si, sample, active):
        if self.profile == "cosine_power":
            wo = square_to_power_cosine_hemisphere(sample, self.m_exponent + 1.0)
            return wo, square_to_power_cosine_hemisphere_pdf(wo, self.m_exponent + 1.0)
        return self._lobe.sample(sample)

    def pdf_outgoing(self, wo):
        """Density (solid angle) of :meth:`sample_outgoing` at local direction ``wo``."""
        if self.profile == "cosine_power":
            return square_to_power_cosine_hemisphere_pdf(wo, self.m_exponent + 1.0)
        return self._lobe.pdf(wo)

    def to_string(self):
        detail = ("exponent=%g" % self.exponent) if self.profile == "cosine_power" else \
            ("values=%s" % self.values.tolist())
        return "DirectionalAreaEmitter[profile=%s, %s]" % (self.profile, detail)
