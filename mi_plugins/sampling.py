"""Shared sampling helpers (Dr.Jit, vectorised).

- :func:`hashed_rng`: a PCG32 seeded by hashing surface-interaction inputs and a
  salt, for fresh random numbers inside plugin methods that receive no sampler
  (e.g. ``Emitter.eval``). Identical inputs and salt give identical numbers.
- :class:`Salt`: a per-call counter held in an opaque Dr.Jit value, so changing
  it does not change the traced kernel (no recompilation).
- :func:`sample_hemisphere` / :func:`hemisphere_pdf`: the direction strategies of
  the simulated-emission estimators.
- :func:`direct_light`: next-event estimation reflected by a BSDF: one visibility-tested
  light sample, or a light and a BSDF sample combined by MIS (``qmc_lighttrace``'s
  diffuse continuations, ``ray_bundle``'s first shot), through the package's emitter
  sampling (:mod:`mi_plugins.lights`: right on textured area lights).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.lights import pdf_emitter_direction, sample_emitter_direction

HEMISPHERE_STRATEGIES = ("uniform", "cosine")


class Salt:
    """A counter that yields a new opaque UInt32 salt at every call."""

    def __init__(self, start=0):
        self.count = int(start)

    def next(self):
        self.count = (self.count + 1) & 0xFFFFFFFF
        return dr.opaque(mi.UInt32, self.count)


def _bits(x):
    return dr.reinterpret_array(mi.UInt32, x)


def hashed_rng(si, salt):
    """PCG32 (one lane per entry of ``si``) seeded from si.p, si.wi, si.uv and ``salt``."""
    v0 = _bits(si.p.x) ^ (_bits(si.p.y) * 0x9E3779B9) ^ (_bits(si.p.z) * 0x85EBCA6B) ^ (_bits(si.uv.x) * 0x27D4EB2F)
    v1 = _bits(si.wi.x) ^ (_bits(si.wi.y) * 0xC2B2AE35) ^ (_bits(si.wi.z) * 0x165667B1) ^ salt
    a, b = mi.sample_tea_32(v0, v1, 8)
    c, d = mi.sample_tea_32(b, a ^ salt, 8)
    state = (mi.UInt64(a) << 32) | mi.UInt64(b)
    seq = (mi.UInt64(c) << 32) | mi.UInt64(d)
    return mi.PCG32(dr.width(state), state, seq)


def direct_light(scene, si, bsdf, light_sample, active, bsdf_sample=None, ctx=None):
    """Direct illumination reflected at ``si`` toward ``si.wi`` (next-event estimation).

    Without ``bsdf_sample``: one emitter sample (:func:`~mi_plugins.lights.sample_emitter_direction`,
    visibility tested), f * Le * G / pdf. With ``bsdf_sample = (u, (u1, u2))``: that
    light sample plus one BSDF sample whose ray is traced to the emission it hits,
    combined by multiple importance sampling (power heuristic), which keeps the
    variance bounded where emitters are large and close (furnaces, corners). Zero where
    ``active`` is false. ``ctx``: the BSDF context (default: every lobe; e.g. only the
    smooth lobes where the delta lobes are estimated otherwise)."""
    ctx = mi.BSDFContext() if ctx is None else ctx
    ds, em_weight = sample_emitter_direction(scene, si, light_sample, active)
    active_l = active & (ds.pdf > 0)
    if bsdf_sample is None:
        f = bsdf.eval(ctx, si, si.to_local(ds.d), active_l)
        return dr.select(active_l, mi.Color3f(f) * em_weight, 0.0)
    f, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), active_l)
    weight_l = dr.select(ds.delta, 1.0, _power_heuristic(ds.pdf, bsdf_pdf))
    result = dr.select(active_l, mi.Color3f(f) * em_weight * weight_l, 0.0)

    bs, bsdf_weight = bsdf.sample(ctx, si, bsdf_sample[0], bsdf_sample[1], active)
    active_b = active & (bs.pdf > 0)
    hit = scene.ray_intersect(si.spawn_ray(si.to_world(bs.wo)), active_b)
    emitter = hit.emitter(scene, active_b)        # a miss sees the environment emitter, if any
    emitted = mi.Color3f(emitter.eval(hit, active_b))
    light_pdf = pdf_emitter_direction(scene, si, mi.DirectionSample3f(scene, hit, si), active_b)
    delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    weight_b = dr.select(delta, 1.0, _power_heuristic(bs.pdf, light_pdf))
    return result + dr.select(active_b, mi.Color3f(bsdf_weight) * emitted * weight_b, 0.0)


def _power_heuristic(pdf_a, pdf_b):
    """a^2 / (a^2 + b^2); 0 where that is not a number, as in Mitsuba's `path`: Mitsuba's
    sphere emitter can return an infinite light pdf with a finite sample weight (measured
    once in 65536 camera points of `ray_bundle` inside Bekaert's analytic sphere), and
    inf / inf would make the pixel NaN."""
    a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
    w = a2 / (a2 + b2)
    return dr.select((a2 > 0) & dr.isfinite(w), w, 0.0)


def sample_hemisphere(strategy, sample):
    """Local direction on the upper hemisphere: 'uniform' or 'cosine'."""
    if strategy == "uniform":
        return mi.warp.square_to_uniform_hemisphere(sample)
    if strategy == "cosine":
        return mi.warp.square_to_cosine_hemisphere(sample)
    raise ValueError("strategy=%r: must be one of %s" % (strategy, ", ".join(HEMISPHERE_STRATEGIES)))


def hemisphere_pdf(strategy, d):
    if strategy == "uniform":
        return mi.warp.square_to_uniform_hemisphere_pdf(d)
    return mi.warp.square_to_cosine_hemisphere_pdf(d)


def square_to_power_cosine_hemisphere(sample, exponent):
    """Direction around +z with density (n + 1)/(2 pi) cos^n(theta) (Phong lobe)."""
    cos_theta = dr.power(sample.x, 1.0 / (exponent + 1.0))
    sin_theta = dr.safe_sqrt(1.0 - cos_theta * cos_theta)
    sin_phi, cos_phi = dr.sincos(dr.two_pi * sample.y)
    return mi.Vector3f(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta)


def square_to_power_cosine_hemisphere_pdf(d, exponent):
    return (exponent + 1.0) * dr.inv_two_pi * dr.power(dr.maximum(d.z, 0.0), exponent)


class IsotropicLobe:
    """Importance sampling of an isotropic hemispherical density given (up to a factor)
    as a function of theta: ``weight(theta)`` (numpy, >= 0) times cos(theta)
    sin(theta) is tabulated on ``resolution`` bins over [0, pi/2] and sampled with a
    piecewise-linear ``mi.ContinuousDistribution``; phi is uniform. :meth:`sample` and
    :meth:`pdf` return the solid-angle density actually sampled (exactly consistent)."""

    #: traversable by Dr.Jit: a frozen function (dr.freeze) that samples a plugin holding
    #: a lobe finds the distribution's arrays among its inputs
    DRJIT_STRUCT = {"distribution": mi.ContinuousDistribution}

    def __init__(self, weight, resolution=2048):
        import numpy as np
        theta = np.linspace(0.0, np.pi / 2, resolution + 1)
        density = np.asarray(weight(theta), dtype=np.float64) * np.cos(theta) * np.sin(theta)
        if not np.all(np.isfinite(density)) or np.any(density < 0) or density.sum() <= 0:
            raise ValueError("IsotropicLobe: the tabulated density must be finite, >= 0 and not all zero")
        self.distribution = mi.ContinuousDistribution(mi.ScalarVector2f(0.0, np.pi / 2), mi.Float(density))

    def sample(self, sample):
        """Local direction and its solid-angle pdf from a 2D sample."""
        theta, pdf_theta = self.distribution.sample_pdf(sample.x)
        sin_t, cos_t = dr.sincos(theta)
        sin_p, cos_p = dr.sincos(dr.two_pi * sample.y)
        wo = mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t)
        return wo, dr.select(sin_t > 0, pdf_theta / (dr.two_pi * sin_t), 0.0)

    def pdf(self, wo):
        theta = dr.acos(dr.clip(wo.z, 0.0, 1.0))
        sin_t = dr.sin(theta)
        pdf_theta = self.distribution.eval_pdf_normalized(theta)
        return dr.select((sin_t > 0) & (wo.z > 0), pdf_theta / (dr.two_pi * sin_t), 0.0)
