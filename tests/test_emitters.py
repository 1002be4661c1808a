"""The `simulated_area` emitter: unbiased emission, all estimators, errors."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mi_plugins import analytic

from test_bsdfs import albedo_by_quadrature

BSDFS = {
    "diffuse": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.8]}},
    "roughconductor": {"type": "roughconductor", "alpha": 0.3},
    "phong": {"type": "phong", "diffuse_reflectance": {"type": "rgb", "value": 0.3},
              "specular_reflectance": {"type": "rgb", "value": 0.6}, "exponent": 10.0},
}


_keep_alive = []


def emitter_on(bsdf, estimator, samples=1, target=2.0):
    scene = mi.load_dict({"type": "scene", "s": {"type": "rectangle", "bsdf": bsdf, "emitter": {
        "type": "simulated_area", "target_radiance": target, "estimator": estimator, "samples": samples}}})
    _keep_alive.append(scene)  # an emitter only holds a weak pointer to its shape
    return scene.emitters()[0], scene.shapes()[0].bsdf()


def emission_samples(emitter, wo, n=200000):
    """n independent evaluations of Le at one point and outgoing direction (lanes differ in uv only)."""
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    si.uv = mi.Point2f(dr.arange(mi.Float, n) / n, 0.0)
    si.wi = mi.Vector3f(*wo)
    return np.array(emitter.eval(si))


@pytest.mark.parametrize("estimator", ["uniform", "cosine", "bsdf"])
@pytest.mark.parametrize("bsdf_name", sorted(BSDFS))
@pytest.mark.parametrize("theta_deg", [10, 60])
def test_mean_emission_is_target_times_one_minus_albedo(bsdf_name, estimator, theta_deg):
    emitter, bsdf = emitter_on(BSDFS[bsdf_name], estimator)
    t = np.radians(theta_deg)
    wo = [float(np.sin(t)), 0.0, float(np.cos(t))]
    values = emission_samples(emitter, wo)
    exact = 2.0 * (1.0 - albedo_by_quadrature(bsdf, wo))
    mean, se = values.mean(axis=1), values.std(axis=1) / np.sqrt(values.shape[1])
    assert np.all(np.abs(mean - exact) < 4 * se + 2e-3), (mean, exact, se)


def test_wrong_target_is_detected_by_the_same_test():
    emitter, bsdf = emitter_on(BSDFS["diffuse"], "cosine", target=2.1)
    wo = [0.0, 0.0, 1.0]
    values = emission_samples(emitter, wo)
    exact = 2.0 * (1.0 - albedo_by_quadrature(bsdf, wo))
    se = values.std(axis=1) / np.sqrt(values.shape[1])
    assert np.any(np.abs(values.mean(axis=1) - exact) > 4 * se + 2e-3)


def test_bsdf_estimator_is_exact_for_diffuse_and_samples_reduce_variance():
    emitter, _ = emitter_on(BSDFS["diffuse"], "bsdf")
    v = emission_samples(emitter, [0.0, 0.0, 1.0], n=1000)
    assert np.allclose(v, 2.0 * (1 - np.array([[0.2], [0.5], [0.8]])), atol=1e-5)
    one, _ = emitter_on(BSDFS["phong"], "uniform", samples=1)
    eight, _ = emitter_on(BSDFS["phong"], "uniform", samples=8)
    v1, v8 = (emission_samples(e, [0.3, 0.0, 0.95]) for e in (one, eight))
    ratio = v1.var(axis=1) / v8.var(axis=1)
    assert np.all((ratio > 6) & (ratio < 10.5)), ratio      # variance ~ 1/M


def test_fresh_numbers_at_each_evaluation():
    emitter, _ = emitter_on(BSDFS["phong"], "uniform")
    a = emission_samples(emitter, [0.0, 0.0, 1.0], n=16)
    b = emission_samples(emitter, [0.0, 0.0, 1.0], n=16)
    assert not np.allclose(a, b)


def _render_error_chain(bsdf):
    case = analytic.constant_radiance_brdf(bsdf, 1.0, "sphere", estimator="uniform", resolution=8)
    try:
        mi.render(case.scene("path"), spp=1)
    except Exception as error:
        chain, e = [], error
        while e is not None:
            chain.append(str(e))
            e = e.__cause__ or e.__context__
        return chain
    return []


def test_delta_bsdf_needs_the_bsdf_estimator():
    import gc
    mirror = {"type": "conductor", "material": "none", "specular_reflectance": {"type": "rgb", "value": 0.5}}
    assert any("delta lobes" in m and "estimator='bsdf'" in m for m in _render_error_chain(mirror))
    gc.collect()  # Dr.Jit traces every live emitter instance: drop the refused scene first
    ok = analytic.constant_radiance_brdf(mirror, 1.0, "sphere", estimator="bsdf", resolution=16)
    res = analytic.check(ok, "path", spp=16, runs=8)
    assert res.passed, res


@pytest.mark.parametrize("params, message", [
    ({}, "'target_radiance'.*required"),
    ({"target_radiance": 0.0}, "target_radiance=.*must be > 0"),
    ({"target_radiance": 1.0, "samples": 0}, "samples=0 must be an integer >= 1"),
    ({"target_radiance": 1.0, "estimator": "importance"}, "estimator='importance' must be one of"),
])
def test_bad_inputs(params, message):
    with pytest.raises(Exception, match=message):
        mi.load_dict({"type": "scene", "s": {"type": "rectangle", "emitter": dict({"type": "simulated_area"},
                                                                                    **params)}})
