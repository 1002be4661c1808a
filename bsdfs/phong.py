"""``phong``: the modified Phong BSDF of Lafortune and Willems.

    f(wi, wo) = kd / pi + ks (n + 2) / (2 pi) cos^n(alpha),

alpha being the angle between ``wo`` and the mirror direction of ``wi``. The
normalisation keeps the albedo at most kd + ks <= 1 (energy conserving), and f is
reciprocal. It is the specular BSDF of the analytic-scenes paper's results.

The user reference (parameters, examples) is the class docstring.

Sampling: the lobe is chosen with probability proportional to the mean of kd and
of ks at the point; the diffuse lobe is sampled cosine-weighted, the specular lobe
by cos^n around the mirror direction (pdf (n + 1)/(2 pi) cos^n alpha); directions
below the surface are rejected (zero weight). ``pdf``/``eval_pdf`` return the
matching mixture density, so MIS weights are consistent with ``sample``.

Scene parameters: ``traverse`` exposes both reflectance textures and the exponent (a
``mi.Float``, opaque in kernels); ``parameters_changed`` re-reads the edited values with
the load-time reader (same checks, same messages) and re-checks kd + ks <= 1; an
invalid edit raises and is undone.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.light.direct import square_to_power_cosine_hemisphere
from mi_plugins.base import editable
from mi_plugins.base.params import Params
from mi_plugins.base.textures import texture_sum_max


def _mirror_direction(wi):
    return mi.Vector3f(-wi.x, -wi.y, wi.z)


def _mean(c):
    return (c[0] + c[1] + c[2]) / 3.0


class PhongBSDF(mi.BSDF):
    r"""
    .. _bsdf-phong:

    ``phong`` (modified Phong, Lafortune and Willems)
    --------------------------------------------------

    f = kd/pi + ks (n+2)/(2 pi) cos^n(alpha), alpha from the mirror direction: energy
    conserving (albedo <= kd + ks <= 1) and reciprocal; the specular BSDF of the
    analytic-scenes paper's results.

    .. pluginparameters::

     * - diffuse_reflectance
       - float, RGB or texture
       - 0.5
       - kd >= 0; exposed, differentiable
     * - specular_reflectance
       - float, RGB or texture
       - 0.2
       - ks >= 0, kd + ks <= 1 in every channel (checked); exposed, differentiable
     * - exponent
       - float
       - 10
       - n >= 0; exposed, differentiable

    Lobe chosen by mean kd vs ks; the specular lobe sampled proportionally to cos^n
    around the mirror direction; ``pdf``/``eval_pdf`` consistent with ``sample``
    (chi-square tested at n = 0, 2, 10, 50). The context's lobe selection is honoured as
    by Mitsuba's BSDFs: component 0 is the diffuse lobe (``DiffuseReflection``), 1 the
    glossy one (``GlossyReflection``); a disabled lobe is left out of eval, pdf and
    sample.

    Exposed parameters (``mi.traverse``): ``diffuse_reflectance.value`` and
    ``specular_reflectance.value`` (or the keys of a texture given there), ``exponent`` (a
    ``mi.Float``). An edit is checked like a value at load; an invalid one raises and is
    undone.

    .. code-block:: python

        {'type': 'phong', 'diffuse_reflectance': {'type': 'rgb', 'value': 0.3},
         'specular_reflectance': {'type': 'rgb', 'value': 0.17}, 'exponent': 10.0}

    .. code-block:: xml

        <bsdf type="phong"><rgb name="diffuse_reflectance" value="0.3"/>
            <rgb name="specular_reflectance" value="0.17"/><float name="exponent" value="10"/></bsdf>
    """


    def __init__(self, props):
        super().__init__(props)
        p = Params(props, self.plugin)
        self.kd, self.ks, self.exponent = self._read(p)
        self.m_exponent = mi.Float(self.exponent)
        self.m_components = [mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide,
                             mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide]
        self.m_flags = self.m_components[0] | self.m_components[1]
        self._derive(p)
        editable.keep_valid(self)

    # ------------------------------------------------------------ parameters
    @staticmethod
    def _read(p):
        """The parameters, read and checked by ``p``: at load and after every edit."""
        return (p.texture("diffuse_reflectance", 0.5, lo=0), p.texture("specular_reflectance", 0.2, lo=0),
                p.float("exponent", 10.0, lo=0))

    def _derive(self, p):
        """The rule between the parameters, and the kernels' view of them (one place for
        load and update)."""
        total = texture_sum_max(self.kd, self.ks)
        if total > 1.0 + 1e-6:
            raise p.conflict(("diffuse_reflectance", "specular_reflectance"),
                             "diffuse_reflectance + specular_reflectance <= 1 in every channel for an "
                             "energy-conserving BSDF (the sum reaches %.4g)" % total)
        dr.make_opaque(self.m_exponent)

    def _exposed(self):
        return {"diffuse_reflectance": self.kd, "specular_reflectance": self.ks, "exponent": self.m_exponent}

    def traverse(self, callback):
        callback.put("diffuse_reflectance", self.kd, mi.ParamFlags.Differentiable)
        callback.put("specular_reflectance", self.ks, mi.ParamFlags.Differentiable)
        # a lobe-shape parameter, flagged like the roughness of Mitsuba's microfacet BSDFs
        callback.put("exponent", self.m_exponent, mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous)

    def _apply(self, p, keys):
        self.exponent = self._read(p)[2]      # the edited textures stay in place
        self._derive(p)

    def parameters_changed(self, keys=()):
        """Re-reads the edited values with the load-time reader: an invalid edit raises its
        ParameterError and is undone (the last valid values are restored)."""
        editable.parameters_changed(self, keys)

    def undo(self, notify=True):
        editable.undo(self, notify)

    # ------------------------------------------------------------ helpers
    @staticmethod
    def _enabled(ctx):
        """(diffuse lobe enabled, glossy lobe enabled) by the context's type mask and
        component selection (component 0: diffuse, 1: glossy), as Mitsuba's BSDFs do."""
        return (ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 0), ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 1))

    def _lobes(self, ctx, si, active):
        kd, ks = self.kd.eval(si, active), self.ks.eval(si, active)
        use_d, use_s = self._enabled(ctx)
        wd, ws = _mean(kd) * use_d, _mean(ks) * use_s
        p_diffuse = dr.select(wd + ws > 0, wd / (wd + ws), 1.0 if use_d else 0.0)
        return kd * use_d, ks * use_s, p_diffuse

    def _value_and_pdf(self, ctx, si, wo, active):
        wi = si.wi
        active = (mi.Bool(active) & (mi.Frame3f.cos_theta(wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
                  & any(self._enabled(ctx)))
        kd, ks, p_diffuse = self._lobes(ctx, si, active)
        n = self.m_exponent
        cos_alpha = dr.dot(_mirror_direction(wi), wo)
        cos_alpha_n = dr.select(cos_alpha > 0, dr.power(dr.maximum(cos_alpha, 0.0), n), 0.0)
        cos_o = mi.Frame3f.cos_theta(wo)
        value = (kd * dr.inv_pi + ks * ((n + 2) * dr.inv_two_pi) * cos_alpha_n) * cos_o
        pdf = p_diffuse * cos_o * dr.inv_pi + (1 - p_diffuse) * ((n + 1) * dr.inv_two_pi) * cos_alpha_n
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    # ------------------------------------------------------------ BSDF interface
    def eval(self, ctx, si, wo, active=True):
        return self._value_and_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self._value_and_pdf(ctx, si, wo, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        return self._value_and_pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        active = mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0) & any(self._enabled(ctx))
        _, _, p_diffuse = self._lobes(ctx, si, active)
        choose_diffuse = sample1 < p_diffuse
        wo_diffuse = mi.warp.square_to_cosine_hemisphere(sample2)
        lobe_local = square_to_power_cosine_hemisphere(sample2, self.m_exponent)
        wo_specular = mi.Frame3f(_mirror_direction(si.wi)).to_world(lobe_local)
        wo = dr.select(choose_diffuse, wo_diffuse, wo_specular)
        value, pdf = self._value_and_pdf(ctx, si, wo, active)
        active &= pdf > 0
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = wo
        bs.pdf = dr.select(active, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(dr.select(choose_diffuse, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
                                              mi.UInt32(+mi.BSDFFlags.GlossyReflection)))
        bs.sampled_component = dr.select(choose_diffuse, mi.UInt32(0), mi.UInt32(1))
        return bs, dr.select(active, value / dr.select(active, pdf, 1.0), 0.0)

    def eval_diffuse_reflectance(self, si, active=True):
        return self.kd.eval(si, active)

    def to_string(self):
        return "PhongBSDF[diffuse_reflectance=%s, specular_reflectance=%s, exponent=%g]" % (
            self.kd, self.ks, self.exponent)
