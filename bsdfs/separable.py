"""``separable``: the symmetric separable BSDF of lightsource testing.

Implements section 2.2 (eq. 9) of the analytic-scenes paper: for a surface with
emission Le(x, w) and a target radiance L~ > max Le,

    f(w', w) = (L~ - Le(w)) (L~ - Le(w')) / (L~ * D),   D = integral (L~ - Le) cos dw
                                                          = pi L~ - integral Le cos dw,

has albedo a(w) = 1 - Le(w)/L~, so a closed scene made of such surfaces has
radiance L~ everywhere, whatever the (isotropic) emission profiles are. A surface
without emission gets f = 1/pi (albedo 1).

The user reference (parameters, examples) is the class docstring.

Sampling: when the emission is spatially uniform, directions are importance sampled
with density proportional to (L~ - Le(w')) cos (channel means; a 2048-bin table in
theta), i.e. exactly proportional to f cos for grey emission; otherwise (textured
radiance, or no emission) cosine-weighted as in the paper. ``pdf`` matches ``sample``.
Note on 'simulated': the paper's estimator puts a random quantity in the
denominator, so its mean is not exactly eq. 9 (Jensen's inequality); the bias is
O(Var/M) and is measured in the tests and the README.

Scene parameters: ``traverse`` exposes ``target_radiance`` (an opaque ``mi.Color3f``);
after an edit of it, or of the referenced emitter (which calls :meth:`emission_changed`),
the rule L~ > max emission is re-checked with the load-time reader and the sampling
table recomputed; an invalid edit raises and is undone.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.light.direct import IsotropicLobe, Salt, hashed_rng
from mi_plugins.base import editable
from mi_plugins.base.params import Params, parameter_error
from mi_plugins.base.textures import as_given, texture_max

NORMALIZATIONS = ("exact", "simulated")


class SeparableBSDF(mi.BSDF):
    r"""
    .. _bsdf-separable:

    ``separable`` (lightsource testing, analytic-scenes paper, section 2.2, eq. 9)
    ------------------------------------------------------------------------------

    f(w', w) = (L~ - Le(w)) (L~ - Le(w')) / (L~ integral (L~ - Le) cos): albedo
    1 - Le(w)/L~, so scenes of such surfaces have radiance L~ for ANY emission profiles.
    Surfaces without emission get f = 1/pi. One lobe, component 0: diffuse without
    emission, glossy with it; a context that does not select it gets zero from eval and
    pdf and no sample, as from Mitsuba's BSDFs.

    .. pluginparameters::

     * - target_radiance
       - float or RGB
       - required
       - L~ > max emission of the surface (checked); exposed, differentiable
     * - emission
       - reference
       - none
       - the shape's own ``directional_area`` emitter, by reference
     * - normalization
       - string
       - ``'exact'``
       - ``'exact'`` (emitter's exact integral) or ``'simulated'`` (paper's M-direction
         estimate; biased, see Findings)
     * - samples
       - int
       - 16
       - M >= 1 for ``'simulated'``

    The BSDF uses exactly the emission of its surface: ``emission`` must reference the
    emitter object of the same shape, and the BSDF refuses (loud error naming the
    shape) an emitter that belongs to another shape; a ``directional_area`` emitter
    refuses a shape whose ``separable`` BSDF does not reference it.

    Exposed parameters (``mi.traverse``): ``target_radiance`` (a ``mi.Color3f``); an edit
    of it or of the emitter's parameters re-checks L~ > max emission (an invalid edit
    raises and is undone).

    .. code-block:: python

        {'type': 'ply', 'filename': 'lamp.ply',
         'emitter': {'type': 'directional_area', 'id': 'lamp_emission', 'exponent': 3.0},
         'bsdf': {'type': 'separable', 'target_radiance': 2.0, 'emission': {'type': 'ref', 'id': 'lamp_emission'}}}

    .. code-block:: xml

        <shape type="ply"><string name="filename" value="lamp.ply"/>
            <emitter type="directional_area" id="lamp_emission"><float name="exponent" value="3"/></emitter>
            <bsdf type="separable"><float name="target_radiance" value="2"/><ref name="emission" id="lamp_emission"/></bsdf>
        </shape>
    """


    def __init__(self, props):
        super().__init__(props)
        p = Params(props, self.plugin)
        self.target, self.emission = self._read(p)
        self.normalization = p.choice("normalization", "exact", NORMALIZATIONS)
        self.samples = p.int("samples", 16, lo=1)
        self.m_target = mi.Color3f(*[float(v) for v in self.target])
        self._checked = False
        self.salt = Salt()
        # one lobe (component 0): diffuse without emission, glossy with it
        self.lobe = mi.BSDFFlags.DiffuseReflection if self.emission is None else mi.BSDFFlags.GlossyReflection
        self.m_components = [self.lobe | mi.BSDFFlags.FrontSide]
        self.m_flags = self.m_components[0]
        self._derive(p)
        editable.keep_valid(self)

    # ------------------------------------------------------------ parameters
    @staticmethod
    def _read(p):
        """(L~, emitter), read and checked by ``p``: at load and after every edit."""
        from mi_plugins.emitters.directional_area import DirectionalAreaEmitter  # the current variant's class
        target = p.rgb("target_radiance", lo=0, lo_open=True, required=True)
        return target, p.reference("emission", DirectionalAreaEmitter,
                                   "a reference to the 'directional_area' emitter of the shape this BSDF "
                                   "sits on (<ref name=\"emission\" id=\"...\"/>)")

    def _derive(self, p):
        """The rule between L~ and the emission, and everything that depends on them (one
        place for load and update): the kernels' opaque L~, the sampling table."""
        if self.emission is not None:
            max_emission = texture_max(self.emission.radiance_texture) * self._max_profile()
            if not np.all(self.target > max_emission):
                raise p.conflict(("target_radiance", "emission"),
                                 "target_radiance must exceed the maximum emission %.6g of the surface in every "
                                 "channel (otherwise the BSDF would be negative)" % max_emission)
        dr.make_opaque(self.m_target)
        self._lobe = self._importance_lobe()

    def traverse(self, callback):
        callback.put("target_radiance", self.m_target, mi.ParamFlags.Differentiable)

    def _exposed(self):
        return {"target_radiance": self.m_target}

    def _given(self):
        given = {"target_radiance": as_given(self.m_target)}
        if self.emission is not None:
            given["emission"] = self.emission
        return given

    def _apply(self, p, keys):
        self.target = self._read(p)[0]
        self._derive(p)

    def parameters_changed(self, keys=()):
        """Re-reads L~ with the load-time reader and re-checks the rule with the emission:
        an invalid edit raises its ParameterError and is undone (see :meth:`undo`)."""
        editable.parameters_changed(self, keys)

    def undo(self, notify=True):
        """Back to the last valid L~ and, as the rule involves them, the emitter's last
        valid parameters."""
        if self.emission is not None:
            self.emission.undo(notify=False)
        editable.undo(self, notify)

    def emission_changed(self):
        """Called by the referenced emitter after an edit of its parameters."""
        self.parameters_changed(["emission"])

    def _importance_lobe(self):
        """Sampling density proportional to (L~ - Le(w')) cos (channel means) when the
        emission is spatially uniform; None (cosine-weighted sampling) otherwise."""
        e = self.emission
        if e is None or e.radiance_texture.is_spatially_varying():
            return None
        r = float(np.mean(np.array(e.radiance_texture.eval(dr.zeros(mi.SurfaceInteraction3f))).ravel()[:3]))
        target = float(np.mean(self.target))
        return IsotropicLobe(lambda theta: target - r * e.profile_at_theta(theta))

    def _max_profile(self):
        e = self.emission
        return 1.0 if e.profile == "cosine_power" else float(np.max(e.values))

    def _check_binding(self):
        """The referenced emitter must be the one of the shape that carries this BSDF."""
        if self._checked or self.emission is None:
            return
        shape = self.emission.get_shape()
        if shape is None or shape.bsdf() is not self:
            raise parameter_error("separable", [("emission", self.emission)],
                                  "a reference to the emitter of the shape this BSDF sits on "
                                  "(<ref name=\"emission\" id=\"...\"/> to that shape's emitter); the emitter "
                                  "referenced is %s"
                                  % ("not attached to any shape" if shape is None
                                     else "attached to shape '%s', which has another BSDF" % shape.id()))
        self._checked = True

    # ------------------------------------------------------------ the formula
    def _emission(self, si, d):
        """Le(x, d) of the surface (Color3f; zero without emission)."""
        if self.emission is None:
            return dr.zeros(mi.Color3f, dr.width(d))
        return self.emission.radiance_texture.eval(si) * self.emission.profile_value(mi.Frame3f.cos_theta(d))

    def _denominator(self, si):
        """L~ * D, D = pi L~ - integral Le cos (exact or simulated)."""
        target = self.m_target
        if self.emission is None:
            return target * target * dr.pi
        if self.normalization == "exact":
            integral = self.emission.radiance_texture.eval(si) * self.emission.hemispherical_integral_ad()
        else:
            rng = hashed_rng(si, self.salt.next())
            integral = dr.zeros(mi.Color3f, dr.width(si.p))
            for _ in range(self.samples):
                d = mi.warp.square_to_uniform_hemisphere(mi.Point2f(rng.next_float32(), rng.next_float32()))
                integral += self._emission(si, d) * mi.Frame3f.cos_theta(d) * dr.two_pi
            integral /= self.samples
        return target * (dr.pi * target - integral)

    def _f(self, si, wo):
        target = self.m_target
        return (target - self._emission(si, si.wi)) * (target - self._emission(si, wo)) / self._denominator(si)

    # ------------------------------------------------------------ BSDF interface
    def _enabled(self, ctx):
        """The context selects the lobe (component 0 of its type), as Mitsuba's BSDFs check."""
        return ctx.is_enabled(self.lobe, 0)

    def eval(self, ctx, si, wo, active=True):
        self._check_binding()
        active = (mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
                  & self._enabled(ctx))
        return dr.select(active, self._f(si, wo) * mi.Frame3f.cos_theta(wo), 0.0)

    def _sample_direction(self, sample2):
        if self._lobe is None:
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            return wo, mi.warp.square_to_cosine_hemisphere_pdf(wo)
        return self._lobe.sample(sample2)

    def _pdf_direction(self, wo):
        if self._lobe is None:
            return mi.warp.square_to_cosine_hemisphere_pdf(wo)
        return self._lobe.pdf(wo)

    def pdf(self, ctx, si, wo, active=True):
        active = (mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
                  & self._enabled(ctx))
        return dr.select(active, self._pdf_direction(wo), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        self._check_binding()
        active = mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0) & self._enabled(ctx)
        wo, pdf = self._sample_direction(sample2)
        active &= (pdf > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo, bs.pdf, bs.eta = wo, dr.select(active, pdf, 0.0), 1.0
        bs.sampled_type = mi.UInt32(+self.lobe)
        bs.sampled_component = mi.UInt32(0)
        weight = self._f(si, wo) * mi.Frame3f.cos_theta(wo) / dr.select(active, pdf, 1.0)
        return bs, dr.select(active, weight, 0.0)

    def to_string(self):
        return "SeparableBSDF[target_radiance=%s, emission=%s, normalization=%s]" % (
            self.target.tolist(), "none" if self.emission is None else self.emission.to_string(),
            self.normalization)
