"""Rough glass lit from inside. Mitsuba's ``roughdielectric`` returns its lobe's positive
``bs.pdf`` for samples whose direction crossed to the other lobe's side, weighs them 0,
and eval() there is the other lobe's (docs/findings.md). The light tracers weigh a bounce
by eval / bs.pdf and take a sample of weight 0 for none. Tests of the tests: the same
glass with its zero weights hidden (:class:`HiddenZeroWeights`), with which the integrators
divide eval by bs.pdf on every sample, as they did before."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.verify.analytic import stats
from mi_plugins.verify.conformance import runner
from mi_plugins.integrators.qmc_lighttrace import particles
T = mi.ScalarTransform4f
GLASS = {"type": "roughdielectric", "alpha": 0.5, "int_ior": 1.5}


class HiddenZeroWeights(mi.BSDF):
    """``GLASS`` whose samples of weight 0 come back with weight 1e-30: a deliberately
    wrong BSDF (an integrator that trusts ``bs.pdf`` alone counts them)."""

    def __init__(self, props):
        super().__init__(props)
        self.inner = mi.load_dict(GLASS)
        self.m_components = [self.inner.flags(0), self.inner.flags(1)]
        self.m_flags = self.inner.flags()

    def sample(self, ctx, si, sample1, sample2, active=True):
        bs, weight = self.inner.sample(ctx, si, sample1, sample2, active)
        hidden = (bs.pdf > 0) & dr.all(mi.Color3f(weight) == 0)
        return bs, dr.select(hidden, mi.Color3f(1e-30), mi.Color3f(weight))

    def eval(self, ctx, si, wo, active=True):
        return self.inner.eval(ctx, si, wo, active)

    def pdf(self, ctx, si, wo, active=True):
        return self.inner.pdf(ctx, si, wo, active)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.inner.eval_pdf(ctx, si, wo, active)

    def to_string(self):
        return "HiddenZeroWeights[%s]" % self.inner


@pytest.fixture(scope="module", autouse=True)
def _hidden_zero_weights():
    mi.register_bsdf("test_hidden_zero_weights", lambda props: HiddenZeroWeights(props))
    yield


def glass(hidden):
    return {"type": "test_hidden_zero_weights"} if hidden else dict(GLASS)


def lantern_room(hidden=False, resolution=16):
    """A closed diffuse room (reflectance 0.5) whose only light is a sphere lamp inside a
    rough glass cube floating in a corner; the camera looks at the far walls and the
    floor: every ray of light left the glass from inside."""
    gray = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}
    return {"type": "scene",
            "sensor": {"type": "perspective", "fov": 70,
                       "to_world": T().look_at([0.6, 0.3, 0.7], [-1.0, -0.4, -0.8], [0, 1, 0]),
                       "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                                "rfilter": {"type": "box"}}},
            "room": {"type": "cube", "flip_normals": True, "bsdf": gray},
            "glass": {"type": "cube", "to_world": T().translate([0.55, -0.55, 0.55]).scale(0.3), "bsdf": glass(hidden)},
            "lamp": {"type": "sphere", "center": [0.6, -0.5, 0.58], "radius": 0.08,
                     "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 20.0}}}}


def test_particle_bounce_factor_is_mitsubas_sample_weight():
    """qmc_lighttrace's factor of a bounce on a flat rough glass (no shading normals) is
    Mitsuba's Importance-mode sample weight on every sample, for light arriving from inside
    beyond the critical angle (cos -0.4, -0.5) and from outside; 0 where that weight is 0.
    Test of the test: with the zero weights hidden (eval / bs.pdf on every sample), most
    samples Mitsuba weighs 0 get a positive factor."""
    n = 1 << 15
    rng = budget.rng(41)
    for hidden in (False, True):
        scene = mi.load_dict({"type": "scene", "slab": {"type": "rectangle", "bsdf": glass(hidden)}})
        for cos in (-0.5, -0.4, 0.5):          # light arriving on the back side is inside the glass
            sin = math.sqrt(1.0 - cos * cos)
            x, y = (rng.uniform(-0.5, 0.5, (2, n)) + [[-sin], [0.0]]).astype(np.float32)
            o = mi.Point3f(mi.Float(x), mi.Float(y), cos)
            ray = mi.Ray3f(o, mi.Vector3f(sin, 0.0, -cos))
            si = scene.ray_intersect(ray)
            bsdf = si.bsdf(ray)
            u = [mi.Float(rng.random(n).astype(np.float32)) for _ in range(3)]
            bs, weight = bsdf.sample(mi.BSDFContext(mi.TransportMode.Importance), si, u[0], mi.Point2f(u[1], u[2]),
                                     si.is_valid())
            factor = particles.adjoint_weight(bsdf, mi.BSDFContext(mi.TransportMode.Radiance), si, bs, weight,
                                                  si.is_valid())
            got, want = np.array(mi.Color3f(factor).x), np.array(mi.Color3f(weight).x)
            assert np.array(si.is_valid()).all()
            if not hidden:
                assert np.all(np.abs(got - want) <= 1e-3 * want + 1e-6), (cos, np.max(np.abs(got - want)))
            elif cos < 0:         # (the samples Mitsuba weighs 0: 11-13 % here, and most count)
                zero = want < 1e-20              # (hidden: 1e-30)
                assert zero.mean() > 0.005 and (got[zero] > 0).mean() > 0.5, (cos, zero.mean(), got[zero])


def _means(scene_dict, integrator, spp, runs, seed):
    """(mean, SE) of the image means of ``runs`` renders."""
    images = runner.render_runs(scene_dict, integrator, spp, [budget.seed(seed) * 1000 + r for r in range(runs)])[0]
    means = images[..., :3].mean(axis=(1, 2, 3))
    return means.mean(), means.std(ddof=1) / math.sqrt(runs)


@pytest.fixture(scope="module")
def reference():
    """path's image mean of the room, 32 runs of 256 spp (at 128 runs: path 0.04142 +- 0.2 %,
    ptracer 0.04151 +- 0.3 %, stochastic_ray -0.3 +- 0.5 %, the gather +0.5 +- 0.4 %, the
    smooth display +0.1 +- 0.3 %)."""
    return _means(lantern_room(), {"type": "path", "max_depth": -1}, 256, 32, 80)


#: (integrator dict, spp, runs, runs of the test of the test) of each light tracer; measured
#: over seed offsets 0-4, their tolerance (Student-t bound) and the hidden zero weights' image:
#: stochastic_ray 5.5-10.6 %, +40 to +88 %; gather 5.3-7.4 %, +29 to +39 %; smooth 7.0-8.5 %,
#: +43 to +62 %
TRACERS = {"stochastic_ray": ({"type": "stochastic_ray", "max_depth": -1}, 32, 16, 8),
           "qmc_lighttrace": ({"type": "qmc_lighttrace", "max_depth": -1}, 16, 16, 4),
           "qmc_lighttrace:smooth": ({"type": "qmc_lighttrace", "max_depth": -1, "display": "smooth"}, 16, 8, 4)}


@pytest.mark.parametrize("name", list(TRACERS))
def test_light_tracers_match_path_with_rough_glass_lit_from_inside(name, reference):
    """The light tracers' image of the room matches path's within the Student-t bound of
    the measured SEs. Test of the test: with the glass's zero weights hidden (the division
    by bs.pdf of every sample), the image is beyond that bound, too bright (``TRACERS``)."""
    integrator, spp, runs, bad_runs = TRACERS[name]
    ref, ref_se = reference
    mean, se = _means(lantern_room(), integrator, spp, runs, 81)
    tolerance = stats.t_quantile_for_z(budget.Z, runs - 1) * math.hypot(se, ref_se)
    budget.close(mean, ref, tolerance / budget.Z, what="%s / path, rough glass lit from inside" % name)
    bad, _ = _means(lantern_room(hidden=True), integrator, spp, bad_runs, 82)
    assert bad - ref > tolerance, (name, bad, ref, tolerance)
