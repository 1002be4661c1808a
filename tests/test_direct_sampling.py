"""Next-event estimation of the displays and of ``ray_bundle``: a BSDF sample (MIS) only
where the light sample alone could have unbounded weights (``direct.near_emitters``,
``direct.needs_bsdf_sample``), the light sample alone at full weight elsewhere.

Checked: which points count as near; the estimate's mean equals that of MIS everywhere,
at near and far points (test of the test: the light sample kept at its MIS weight
without the BSDF sample is caught); the displays' samples stay bounded next to emitting
edges (test of the test: with nothing counted as near, they are not).
"""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.verify import analytic
from mi_plugins.light import direct
from mi_plugins.light.sources import sample_emitter_direction

T = mi.ScalarTransform4f
LAMP = 0.3         # side of the square lamp under the ceiling (y = 1.9)
SAMPLES = 4096     # samples per point


def _room(extra=None):
    """A floor (y = 0), a wall (x = -0.17, up to y = 2) and a small lamp facing down next to it."""
    d = {"type": "scene",
         "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90), "bsdf": {"type": "diffuse"}},
         "wall": {"type": "rectangle", "to_world": T().translate([-0.17, 1, 0]).rotate([0, 1, 0], 90),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.4, 0.3]}}},
         "lamp": {"type": "rectangle", "to_world": T().translate([0, 1.9, 0]).rotate([1, 0, 0], 90)
                  .scale([LAMP / 2, LAMP / 2, 1]),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 10.0}}}}
    d.update(extra or {})
    return mi.load_dict(d)


def _points(scene):
    """Surface interactions: 4 floor points (far from the lamp) and 4 wall points next to
    it, in that order, each facing a viewer at (0, 1, 0)."""
    targets = np.array([[0.5, 0, 0.5], [-0.2, 0, -0.6], [0.8, 0, -0.3], [0.0, 0, 0.0],
                        [-0.17, 1.89, 0.0], [-0.17, 1.88, 0.1], [-0.17, 1.85, -0.1], [-0.17, 1.7, 0.05]])
    o = np.array([0.0, 1.0, 0.0])
    d = targets - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(np.full(len(d), c)) for c in o]), mi.Vector3f(*[mi.Float(d[:, c])
                                                                                          for c in range(3)]))
    return scene.ray_intersect(ray)


def test_near_emitters_marks_the_points_next_to_emitting_shapes():
    scene = _room()
    near = np.array(direct.near_emitters(scene, _points(scene).p))
    assert not near[:4].any() and near[4:].all(), near
    # no emitting shape: nothing is near (a point light's samples have bounded weights)
    lit = _room({"lamp": {"type": "point", "position": [0, 1.9, 0]}})
    assert not np.array(direct.near_emitters(lit, _points(lit).p)).any()
    # an environment emitter, or more emitting shapes than the limit: everything is near
    sky = _room({"sky": {"type": "constant"}})
    assert np.array(direct.near_emitters(sky, _points(sky).p)).all()
    many = {"l%d" % i: {"type": "rectangle", "to_world": T().translate([0.1 * i, 1.95, 0]).scale(0.01),
                        "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}}
            for i in range(direct.MAX_NEAR_SHAPES + 1)}
    crowded = _room(many)
    assert np.array(direct.near_emitters(crowded, _points(crowded).p)).all()


def _estimates(scene, how, seed):
    """(points, SAMPLES) luminance of the direct light at the 8 points: ``how`` 'needed'
    (the package's rule), 'everywhere' (MIS at every point) or 'broken' (the light
    sample at its MIS weight, no BSDF sample: a deliberately wrong estimator)."""
    si0 = _points(scene)
    n = dr.width(si0.p)
    lane = dr.arange(mi.UInt32, n * SAMPLES) // SAMPLES
    si = dr.gather(mi.SurfaceInteraction3f, si0, lane)
    bsdf = si.bsdf()
    rng = mi.PCG32(n * SAMPLES, budget.seed(seed), dr.arange(mi.UInt64, n * SAMPLES))
    light = mi.Point2f(rng.next_float32(), rng.next_float32())
    bs = (rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()))
    active = mi.Bool(True)
    if how == "broken":
        ds, em = sample_emitter_direction(scene, si, light, active)
        f, pdf = bsdf.eval_pdf(mi.BSDFContext(), si, si.to_local(ds.d), ds.pdf > 0)
        value = mi.Color3f(f) * em * direct._power_heuristic(ds.pdf, pdf)
    else:
        mis = direct.needs_bsdf_sample(scene, si, bsdf) if how == "needed" else True
        value = direct.direct_light(scene, si, bsdf, light, active, bs, mis=mis)
    return np.array(mi.luminance(value)).reshape(n, SAMPLES)


def _difference(a, b):
    """Per point: the difference of the means of a and b, and its standard error."""
    se = np.sqrt(a.var(axis=1, ddof=1) / a.shape[1] + b.var(axis=1, ddof=1) / b.shape[1])
    return a.mean(axis=1) - b.mean(axis=1), se


def test_light_sample_alone_far_from_emitters_keeps_the_mean():
    scene = _room()
    everywhere = _estimates(scene, "everywhere", 1)
    assert (everywhere.mean(axis=1) > 0).all()
    diff, se = _difference(_estimates(scene, "needed", 2), everywhere)
    budget.close(diff, 0.0, se, what="direct light: MIS where needed - MIS everywhere")
    # test of the test: light samples kept at their MIS weight without the BSDF sample
    # lose its share, and the comparison sees it (at the points next to the lamp, where
    # that share is large)
    diff, se = _difference(_estimates(scene, "broken", 2), everywhere)
    assert (np.abs(diff) > budget.Z * se)[4:].any(), (diff, se)


@pytest.mark.parametrize("integrator", ["qmc_lighttrace", "ray_bundle"])
def test_smooth_display_stays_bounded_at_emitting_edges(integrator, monkeypatch):
    """The Keller cube (every face emits L = 1/2) seen at its edges, one camera sample per
    pixel at 128 x 128: no pixel of the smooth display exceeds 5 L; test of the test:
    with no point counted as near (light samples alone) some pixel does."""
    def peak():
        case = analytic.keller_cube(resolution=128)
        params = dict(samples=20000) if integrator == "qmc_lighttrace" else dict(iterations=4)
        scene = case.scene(dict(type=integrator, display="smooth", **params))
        return float(np.array(mi.render(scene, spp=1, seed=budget.seed(23))).max()) / 0.5

    assert peak() < 5
    monkeypatch.setattr(direct, "near_emitters", lambda scene, p: dr.zeros(mi.Bool, dr.width(p)))
    assert peak() > 5
