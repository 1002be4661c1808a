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


_keep_alive = []  # scenes a test keeps alive (emitters hold weak pointers to their shapes)


@pytest.fixture(autouse=True)
def _release_scenes():
    yield
    import gc
    _keep_alive.clear()  # Dr.Jit traces every live emitter instance in each render
    gc.collect()


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


# ----------------------------------------------------------------------------- directional_area
from mitsuba.chi2 import ChiSquareTest, SphericalDomain  # noqa: E402

PROFILES = {
    "cos0": {"profile": "cosine_power", "exponent": 0.0},
    "cos4": {"profile": "cosine_power", "exponent": 4.0},
    "cos40": {"profile": "cosine_power", "exponent": 40.0},
    "table": {"profile": "tabulated", "values": "1, 0.5, 2, 0.1"},
}


def directional(params, radiance=1.0):
    scene = mi.load_dict({"type": "scene", "r": {"type": "rectangle", "emitter": dict(
        {"type": "directional_area", "radiance": radiance}, **params)}})
    _keep_alive.append(scene)
    return scene.emitters()[0]


def _emission_chi2(emitter, pdf_emitter=None, tmp_path=None):
    pdf_emitter = pdf_emitter or emitter

    def sample_func(u):
        return emitter.sample_outgoing(dr.zeros(mi.SurfaceInteraction3f, dr.width(u)), u, True)[0]

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func,
                         pdf_func=lambda d: pdf_emitter.pdf_outgoing(d), sample_dim=2, ires=32)
    return test.run()


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_directional_emission_sampling_matches_its_pdf(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert _emission_chi2(directional(PROFILES[name]))


def test_directional_chi2_rejects_a_wrong_pdf(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert not _emission_chi2(directional(PROFILES["cos4"]), directional({"exponent": 6.0}))


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_hemispherical_integral_and_power_are_exact(name):
    e = directional(PROFILES[name], radiance=[1.0, 2.0, 3.0])
    n = 1 << 21
    rng = np.random.default_rng(5)
    d = mi.warp.square_to_uniform_hemisphere(mi.Point2f(rng.random(n), rng.random(n)))
    g = np.array(e.profile_value(d.z) * d.z) * 2 * np.pi
    assert abs(g.mean() - e.hemispherical_integral()) < 4 * g.std() / np.sqrt(n)
    assert np.allclose(e.total_power(), 4.0 * np.array([1, 2, 3]) * e.hemispherical_integral(), rtol=1e-5)


def test_light_tracer_weights_integrate_to_the_power():
    e = directional(PROFILES["table"], radiance=0.5)
    n = 1 << 20
    rng = np.random.default_rng(9)
    _, w = e.sample_ray(0.0, 0.5, mi.Point2f(rng.random(n), rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    w = np.array(w)[0]
    assert abs(w.mean() - e.total_power()[0]) < 4 * w.std() / np.sqrt(n) + 1e-5 * w.mean()
    assert w.std() < 1e-3 * w.mean()  # importance sampling proportional to profile * cos


@pytest.mark.parametrize("params, message", [
    ({"profile": "gauss"}, "profile='gauss' must be one of"),
    ({"exponent": -2.0}, "exponent=-2.0 must be >= 0"),
    ({"profile": "tabulated"}, "needs 'values'"),
    ({"profile": "tabulated", "values": "1"}, "at least 2"),
    ({"profile": "tabulated", "values": "1, -1"}, "at least 2 finite values >= 0"),
    ({"radiance": -1.0}, "radiance must be >= 0"),
])
def test_directional_bad_inputs(params, message):
    with pytest.raises(Exception, match=message):
        directional(params)


def test_mirror_sphere_directional_exact_image_by_hand():
    """L(theta) = Le(theta)/(1-k) with cos(theta) = -d.n at the camera ray's hit (numpy)."""
    case = analytic.mirror_sphere(0.6, {"type": "directional_area", "exponent": 4.0, "radiance": 0.8}, resolution=8)
    exact = case.expected(supersampling=1)          # pixel centres
    scene = case.scene()
    sensor = scene.sensors()[0]
    i = np.arange(64)
    pos = mi.Point2f((i % 8 + 0.5) / 8, (i // 8 + 0.5) / 8)
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    o, d = np.array(ray.o), np.array(ray.d)
    b = (o * d).sum(axis=0)
    t = -b + np.sqrt(b * b - ((o * o).sum(axis=0) - 1.0))     # exit point of the unit sphere
    p = o + t * d
    cos_theta = (d * p).sum(axis=0)                             # inward normal -p, direction -d
    by_hand = 0.8 * cos_theta ** 4 / (1 - 0.6)
    assert np.allclose(exact[..., 0].ravel(), by_hand, rtol=1e-3)
    assert by_hand.std() > 0.05
