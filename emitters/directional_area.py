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
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.emitters.surface_emitter import SurfaceEmitter
from mi_plugins.sampling import (IsotropicLobe, square_to_power_cosine_hemisphere,
                                 square_to_power_cosine_hemisphere_pdf)
from mi_plugins.params import NOT_GIVEN, Params, parameter_error

PROFILES = ("cosine_power", "tabulated")


def tabulated_hemispherical_integral(values):
    """Exact 2 pi * integral_0^{pi/2} p(theta) cos(theta) sin(theta) dtheta for p piecewise
    linear in theta on a uniform grid."""
    k = len(values) - 1
    t = np.linspace(0.0, np.pi / 2, k + 1)
    total = 0.0
    for i in range(k):
        t0, t1, p0, p1 = t[i], t[i + 1], values[i], values[i + 1]
        b = (p1 - p0) / (t1 - t0)
        a = p0 - b * t0
        # integral of (a + b t) sin(2t)/2 dt = -a cos(2t)/4 + b (-t cos(2t)/4 + sin(2t)/8)
        prim = lambda x: -a * np.cos(2 * x) / 4 + b * (-x * np.cos(2 * x) / 4 + np.sin(2 * x) / 8)
        total += prim(t1) - prim(t0)
    return 2 * np.pi * total


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
       - >= 0, spatial factor
     * - profile
       - string
       - ``'cosine_power'``
       - ``'cosine_power'`` or ``'tabulated'``
     * - exponent
       - float
       - 1.0
       - n >= 0 of cos^n (0 = diffuse); only with ``'cosine_power'``
     * - values
       - string of floats
       - required for ``'tabulated'``
       - >= 2 values >= 0, not all 0: profile at theta uniformly spaced over [0, pi/2],
         linear in theta; only with ``'tabulated'``

    Emission directions are importance sampled proportionally to profile x cos (exact
    for cos^n, a 2048-bin piecewise-linear table otherwise; chi-square tested).
    ``emitter.hemispherical_integral()`` is the exact integral of profile x cos,
    ``emitter.total_power()`` the exact power (uniform radiance; textures: numeric).

    .. code-block:: python

        'emitter': {'type': 'directional_area', 'profile': 'tabulated', 'values': '0.2, 1.2, 1.8, 0.4',
                    'radiance': {'type': 'rgb', 'value': [0.6, 0.9, 1.0]}}

    .. code-block:: xml

        <emitter type="directional_area"><string name="profile" value="cosine_power"/>
            <float name="exponent" value="4"/><rgb name="radiance" value="0.8, 0.5, 0.3"/></emitter>
    """

    def __init__(self, props):
        super().__init__(props)
        p = Params(props, "directional_area")
        self.radiance_texture = p.texture("radiance", 1.0, lo=0)
        self.profile = p.choice("profile", "cosine_power", PROFILES)
        exponent = p.float("exponent", 1.0, lo=0)
        values = p.floats("values", lo=0, min_count=2)
        if self.profile == "cosine_power":
            if values is not None:
                raise p.conflict(("values", "profile"), "'values' only with profile='tabulated'")
            self.exponent, self.values = exponent, None
        else:
            if p.given("exponent"):
                raise p.conflict(("exponent", "profile"), "'exponent' only with profile='cosine_power'")
            if values is None:
                raise p.conflict(("values", "profile"), "profile='tabulated' needs 'values' (at least 2 profile "
                                 "samples >= 0 over theta in [0, pi/2], e.g. '1, 0.5, 0')")
            if not np.any(values > 0):
                raise p.error("values", "a string of at least 2 comma-separated finite numbers >= 0, not all 0 "
                                        "(these values emit nothing)")
            self.values = values
            self._table = mi.Float(self.values)
            # importance sampling proportional to profile * cos, tabulated in theta
            self._lobe = IsotropicLobe(self.profile_at_theta)

    # ----------------------------------------------------------- the profile
    def profile_value(self, cos_theta):
        """profile(cos theta) (Float)."""
        if self.profile == "cosine_power":
            return dr.power(dr.maximum(cos_theta, 0.0), self.exponent)
        theta = dr.acos(dr.clip(cos_theta, 0.0, 1.0))
        pos = theta / (dr.pi / 2) * (len(self.values) - 1)
        i = mi.UInt32(dr.minimum(dr.floor(pos), len(self.values) - 2))
        f = pos - mi.Float(i)
        v0 = dr.gather(mi.Float, self._table, i)
        v1 = dr.gather(mi.Float, self._table, i + 1)
        return dr.fma(f, v1 - v0, v0)

    def profile_at_theta(self, theta):
        """profile at polar angles ``theta`` (numpy, for tabulating densities)."""
        theta = np.asarray(theta, dtype=np.float64)
        if self.profile == "cosine_power":
            return np.power(np.maximum(np.cos(theta), 0.0), self.exponent)
        return np.interp(theta, np.linspace(0.0, np.pi / 2, len(self.values)), self.values)

    def hemispherical_integral(self):
        """Exact integral of profile(cos theta) cos(theta) over the hemisphere."""
        if self.profile == "cosine_power":
            return 2 * np.pi / (self.exponent + 2)
        return float(tabulated_hemispherical_integral(self.values))

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
            wo = square_to_power_cosine_hemisphere(sample, self.exponent + 1.0)
            return wo, square_to_power_cosine_hemisphere_pdf(wo, self.exponent + 1.0)
        return self._lobe.sample(sample)

    def pdf_outgoing(self, wo):
        """Density (solid angle) of :meth:`sample_outgoing` at local direction ``wo``."""
        if self.profile == "cosine_power":
            return square_to_power_cosine_hemisphere_pdf(wo, self.exponent + 1.0)
        return self._lobe.pdf(wo)

    def to_string(self):
        detail = ("exponent=%g" % self.exponent) if self.profile == "cosine_power" else \
            ("values=%s" % self.values.tolist())
        return "DirectionalAreaEmitter[profile=%s, %s]" % (self.profile, detail)
