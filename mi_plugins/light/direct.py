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
  sampling (:mod:`mi_plugins.light.sources`: right on textured area lights).
- :func:`near_emitters`: the points close enough to an emitting shape for its light
  samples' weights to be unbounded, where the BSDF sample of :func:`direct_light` is
  needed (elsewhere the light sample alone has bounded weights and costs one ray).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.light.sources import pdf_emitter_direction, sample_emitter_direction

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


#: more emitting shapes than this: :func:`near_emitters` counts every point as near (a test
#: per shape in every lane would cost more than the BSDF samples it saves)
MAX_NEAR_SHAPES = 16


def near_emitters(scene, p):
    """Per lane: ``p`` lies within the bounding box of an emitting shape grown on every
    side by the larger of the box's diagonal and the square root of the shape's area.
    Beyond that distance r every point of the shape has A / r^2 < 1, so a light sample of
    it (Le A cos cos / r^2 with uniform area sampling, less with Mitsuba's solid-angle
    sampling of spheres) has a weight of at most Le times the BSDF's value: no BSDF
    sample is needed there. Delta emitters (point, spot, directional) count as far: a
    BSDF sample never finds them. True everywhere where the scene has an environment
    emitter (its light samples follow its brightness, not the surface's cosine, and
    fall behind the surface where the bright part does: BSDF samples keep that variance
    down) or more than ``MAX_NEAR_SHAPES`` emitting shapes. The answer depends on the
    point alone, never on a sample, so an estimator that takes MIS only where it is true
    stays unbiased; a box out of date (an emitter moved after a frozen kernel was
    recorded) changes the noise, never the mean."""
    emitters = scene.emitters()
    shapes = [e.get_shape() for e in emitters if e.get_shape() is not None]
    near = dr.zeros(mi.Bool, dr.width(p))
    if len(shapes) > MAX_NEAR_SHAPES or any(mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) for e in emitters):
        return near | True
    for shape in shapes:        # a few emitting shapes at most (MAX_NEAR_SHAPES)
        box = shape.bbox()      # (the area stays a Dr.Jit value: nothing is evaluated inside frozen kernels)
        grow = dr.maximum(float(dr.norm(box.extents())), dr.sqrt(dr.maximum(shape.surface_area(), 0.0)))
        low, high = mi.Point3f(box.min) - grow, mi.Point3f(box.max) + grow
        near |= dr.all((p >= low) & (p <= high))
    return near


def needs_bsdf_sample(scene, si, bsdf):
    """Per lane: the direct light at ``si`` needs a BSDF sample beside its light sample
    (MIS in :func:`direct_light`): near an emitting shape (:func:`near_emitters`), or a
    BSDF with other lobes than diffuse reflection (a glossy lobe's value is not bounded:
    its highlight of a distant light is found by BSDF samples)."""
    lobes = mi.UInt32(bsdf.flags()) & mi.UInt32(int(mi.BSDFFlags.All))
    return near_emitters(scene, si.p) | (lobes != int(mi.BSDFFlags.DiffuseReflection))


def direct_light(scene, si, bsdf, light_sample, active, bsdf_sample=None, ctx=None, mis=True):
    """Direct illumination reflected at ``si`` toward ``si.wi`` (next-event estimation).

    Without ``bsdf_sample``: one emitter sample (:func:`~mi_plugins.light.sources.sample_emitter_direction`,
    visibility tested), f * Le * G / pdf. With ``bsdf_sample = (u, (u1, u2))``: that
    light sample plus one BSDF sample whose ray is traced to the emission it hits,
    combined by multiple importance sampling (power heuristic), which keeps the
    variance bounded where emitters are large and close (furnaces, corners). ``mis``
    (Bool per lane, e.g. :func:`near_emitters`): the lanes that take the BSDF sample;
    the others keep the light sample alone, at full weight. Zero where ``active`` is
    false. ``ctx``: the BSDF context (default: every lobe; e.g. only the smooth lobes
    where the delta lobes are estimated otherwise)."""
    ctx = mi.BSDFContext() if ctx is None else ctx
    ds, em_weight = sample_emitter_direction(scene, si, light_sample, active)
    active_l = active & (ds.pdf > 0)
    if bsdf_sample is None:
        f = bsdf.eval(ctx, si, si.to_local(ds.d), active_l)
        return dr.select(active_l, mi.Color3f(f) * em_weight, 0.0)
    f, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), active_l)
    active = active & mis
    weight_l = dr.select(ds.delta | ~active, 1.0, _power_heuristic(ds.pdf, bsdf_pdf))
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
