"""``simulated_area``: the simulated-emission light source of BRDF testing.

Implements section 2.1 of Szirmay-Kalos, Kovács and Abbas, "Testing Monte-Carlo
global illumination methods with analytically computable scenes": in a closed
scene, if every surface emits

    Le(x, w) = L~ (1 - a(x, w)),   a(x, w) = integral of f(w', x, w) cos(theta') dw',

the radiance is L~ everywhere, whatever the BSDFs are. The albedo a is estimated
afresh at every evaluation with M random directions (eq. 4), so the emission is a
random function whose mean is exactly L~ (1 - a): Monte-Carlo integrators that
average over samples still converge to L~.

The user reference (parameters, examples) is the class docstring.

The emitter uses the BSDF of the shape it is attached to. Single estimates can be
negative (an unbiased estimate of 1 - a from one direction can exceed 1); that is
inherent to the method and averages out. Le is evaluated for the outgoing
direction w = si.wi; the BSDF is queried with si.wi = w and wo = w' (its value
includes cos(theta')), i.e. the albedo for light leaving in direction w.

Scene parameters: ``traverse`` exposes ``target_radiance`` (an opaque ``mi.Color3f``);
an edit is re-checked by the load-time reader (an invalid one raises and is undone).
The albedo is estimated afresh at every evaluation, so an edit of the shape's BSDF
needs nothing here.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.emitters.surface_emitter import SurfaceEmitter
from mi_plugins.base.params import Params, parameter_error
from mi_plugins.light.direct import Salt, hashed_rng, hemisphere_pdf, sample_hemisphere

ESTIMATORS = ("uniform", "cosine", "bsdf")


class SimulatedAreaEmitter(SurfaceEmitter):
    r"""
    .. _emitter-simulated_area:

    ``simulated_area`` (simulated emission for BRDF testing, analytic-scenes paper, section 2.1)
    --------------------------------------------------------------------------------------------

    Le(x, w) = L~ (1 - a(x, w)) with the albedo a of the surface's own BSDF estimated
    afresh at each evaluation (eq. 4): a closed scene whose surfaces all carry it has
    radiance L~ everywhere, for ANY BSDF. Works with ``path``, ``volpath``, ``ptracer``
    (eval, next-event estimation, emission sampling). Exposed parameter (``mi.traverse``):
    ``target_radiance`` (a ``mi.Color3f``); an edit is checked like a value at load (an
    invalid one raises and is undone).

    .. pluginparameters::

     * - target_radiance
       - float or RGB
       - required
       - L~ > 0; exposed, differentiable
     * - samples
       - int
       - 1
       - M >= 1 directions per evaluation
     * - estimator
       - string
       - ``'uniform'``
       - ``'uniform'`` (paper eq. 4), ``'cosine'``, ``'bsdf'`` (the BSDF's own
         ``sample()``: lowest variance, the only one valid for delta BSDFs; the others
         are refused there with an error)

    .. code-block:: python

        {'type': 'ply', 'filename': 'wall.ply',
         'bsdf': {'type': 'roughconductor', 'alpha': 0.3},
         'emitter': {'type': 'simulated_area', 'target_radiance': 1.0, 'estimator': 'bsdf'}}

    .. code-block:: xml

        <shape type="ply"><string name="filename" value="wall.ply"/>
            <bsdf type="roughconductor"><float name="alpha" value="0.3"/></bsdf>
            <emitter type="simulated_area"><float name="target_radiance" value="1"/>
                <string name="estimator" value="bsdf"/></emitter>
        </shape>

    Single estimates can be negative (unbiased estimates of 1 - a can exceed 1 for
    glossy BSDFs with ``'uniform'``/``'cosine'``); see Findings for what that does to
    Russian roulette in ``ptracer``. Measured noise it adds
    (``benchmarks/simulated_emission_noise.py``, Sierpinski, diffuse 0.47, 16 spp):
    ``path`` RMSE x1.91 (uniform, M=1), x1.28 (uniform, M=4), x1.00 (cosine, bsdf:
    zero-variance for diffuse); ``ptracer`` x1.12 / x1.04 / x1.00; Phong n=10 uniform
    M=1: x2.44 (``path``), x1.31 (``ptracer``).
    """


    def __init__(self, props):
        super().__init__(props)
        p = Params(props, self.plugin)
        self.target = self._read(p)
        self.samples = p.int("samples", 1, lo=1)
        self.estimator = p.choice("estimator", "uniform", ESTIMATORS)
        self.salt = Salt()
        self.m_target = mi.Color3f(*self.target)
        self._derive()
        self._keep_valid()

    # ---------------------------------------------------------- scene parameters
    @staticmethod
    def _read(p):
        """L~ (a list of 3 floats), read and checked by ``p``: at load and after every edit."""
        return p.rgb("target_radiance", lo=0, lo_open=True, required=True).tolist()

    def traverse(self, callback):
        super().traverse(callback)
        callback.put("target_radiance", self.m_target, mi.ParamFlags.Differentiable)

    def _exposed(self):
        return {"target_radiance": self.m_target}

    def _apply(self, p, keys):
        self.target = self._read(p)
        self._derive()

    def _derive(self):
        """The kernels' view of the parameters (one place for load and update)."""
        dr.make_opaque(self.m_target)

    def _bsdf(self):
        bsdf = self._shape().bsdf()
        if self.estimator != "bsdf" and mi.has_flag(bsdf.flags(), mi.BSDFFlags.Delta):
            raise parameter_error("simulated_area", [("estimator", self.estimator)],
                                  "'bsdf' here: the BSDF of shape '%s' has delta lobes, which estimator=%r "
                                  "cannot sample; use estimator='bsdf'" % (self._shape().id(), self.estimator))
        return bsdf

    def albedo_estimate(self, si, wo, active):
        """Unbiased estimate of a(x, wo) from ``samples`` directions (Color3f)."""
        bsdf = self._bsdf()
        rng = hashed_rng(si, self.salt.next())
        ctx = mi.BSDFContext(mi.TransportMode.Radiance)
        query = mi.SurfaceInteraction3f(si)
        query.wi = wo
        total = dr.zeros(mi.Color3f, dr.width(wo))
        for _ in range(self.samples):  # M is a small constant: unrolled into the kernel
            u1, u2 = rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32())
            if self.estimator == "bsdf":
                bs, weight = bsdf.sample(ctx, query, u1, u2, active)
                total += dr.select(active & (bs.pdf > 0), weight, 0.0)
            else:
                d = sample_hemisphere(self.estimator, u2)
                pdf = hemisphere_pdf(self.estimator, d)
                valid = active & (pdf > 0)  # cosine sampling can return grazing d with pdf 0
                value = bsdf.eval(ctx, query, d, valid)
                total += dr.select(valid, value / dr.select(valid, pdf, 1.0), 0.0)
        return total / self.samples

    def radiance(self, si, wo, active):
        return self.m_target * (1.0 - self.albedo_estimate(si, wo, active))

    def to_string(self):
        return "SimulatedAreaEmitter[target_radiance=%s, samples=%d, estimator=%s]" % (
            self.target, self.samples, self.estimator)
