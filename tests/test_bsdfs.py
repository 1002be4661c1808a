"""The `phong` BSDF: sampling (chi-square), reciprocity, energy, bad inputs."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # mitsuba.chi2 writes chi2_data.py on rejection
    yield
    # Dr.Jit traces every live plugin instance of a kind in each render: release this
    # test's scenes (and any deliberately broken instance) before the next test.
    import gc
    _scenes.clear()
    gc.collect()


_scenes = []  # scenes a test keeps alive (emitters hold weak pointers to their shapes)


def phong_xml(n, kd=0.3, ks=0.6):
    return ('<float name="exponent" value="%g"/><rgb name="diffuse_reflectance" value="%g"/>'
            '<rgb name="specular_reflectance" value="%g"/>' % (n, kd, ks))


def chi2(sample_func, pdf_func):
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func, sample_dim=3)
    return test.run(), test


@pytest.mark.parametrize("n, wi", [(10, [0.3, 0.1, 0.9]), (2, [0.7, 0.0, 0.3]), (50, [0.0, 0.0, 1.0]),
                                   (0, [0.5, 0.5, 0.5])])
def test_phong_sampling_matches_pdf(n, wi):
    sample_func, pdf_func = BSDFAdapter("phong", phong_xml(n), wi=dr.normalize(mi.ScalarVector3f(wi)))
    ok, test = chi2(sample_func, pdf_func)
    assert ok, test.messages


def test_chi2_rejects_a_wrong_pdf():
    wi = dr.normalize(mi.ScalarVector3f(0.3, 0.1, 0.9))
    sample_func, _ = BSDFAdapter("phong", phong_xml(10), wi=wi)
    _, wrong_pdf = BSDFAdapter("phong", phong_xml(14), wi=wi)   # pdf of another exponent
    ok, _ = chi2(sample_func, wrong_pdf)
    assert not ok


def _phong(n=10, kd=0.3, ks=0.6):
    return mi.load_dict({"type": "phong", "exponent": float(n), "diffuse_reflectance": {"type": "rgb", "value": kd},
                         "specular_reflectance": {"type": "rgb", "value": ks}})


def _random_dirs(n, seed):
    rng = np.random.default_rng(seed)
    return mi.warp.square_to_uniform_hemisphere(mi.Point2f(rng.random(n), rng.random(n)))


def test_phong_is_reciprocal():
    bsdf, ctx = _phong(), mi.BSDFContext()
    a, b = _random_dirs(10000, 1), _random_dirs(10000, 2)
    si = dr.zeros(mi.SurfaceInteraction3f, 10000)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = a
    f_ab = bsdf.eval(ctx, si, b) / mi.Frame3f.cos_theta(b)
    si.wi = b
    f_ba = bsdf.eval(ctx, si, a) / mi.Frame3f.cos_theta(a)
    assert np.allclose(np.array(f_ab), np.array(f_ba), rtol=1e-4, atol=1e-6)


def albedo_by_quadrature(bsdf, wi, n=512):
    """a(wi) = integral of eval(wi, wo) dwo by the midpoint rule in (cos theta, phi)."""
    iz, iphi = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(2 * n) + 0.5) / (2 * n), indexing="ij")
    z, phi = iz.ravel(), 2 * np.pi * iphi.ravel()
    r = np.sqrt(1 - z * z)
    wo = mi.Vector3f(r * np.cos(phi), r * np.sin(phi), z)
    si = dr.zeros(mi.SurfaceInteraction3f, z.size)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*wi)
    value = np.array(bsdf.eval(mi.BSDFContext(), si, wo))
    return value.mean(axis=1) * 2 * np.pi


@pytest.mark.parametrize("theta_deg", [0, 45, 80])
def test_phong_albedo_at_most_kd_plus_ks_and_sample_weights_agree(theta_deg):
    bsdf = _phong(10, 0.3, 0.6)
    t = np.radians(theta_deg)
    wi = [float(np.sin(t)), 0.0, float(np.cos(t))]
    a = albedo_by_quadrature(bsdf, wi)
    assert np.all(a <= 0.9 + 1e-3) and np.all(a >= 0.3 - 1e-3)
    # the mean sample weight of sample() estimates the same albedo
    n = 200000
    rng = np.random.default_rng(3)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*wi)
    _, w = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    w = np.array(w)
    se = w.std(axis=1) / np.sqrt(n)
    assert np.all(np.abs(w.mean(axis=1) - a) < 4 * se + 1e-3)


@pytest.mark.parametrize("params, message", [
    ({"diffuse_reflectance": 0.7, "specular_reflectance": 0.5}, "must be <= 1"),
    ({"exponent": -1.0}, "exponent=-1.0 must be >= 0"),
    ({"diffuse_reflectance": -0.1}, "must be >= 0"),
])
def test_phong_bad_inputs(params, message):
    with pytest.raises(Exception, match=message):
        mi.load_dict(dict({"type": "phong"}, **params))


# ----------------------------------------------------------------------------- separable


def separable_on_emitter(target=3.0, exponent=3.0, radiance=1.5, normalization="exact", profile=None):
    emitter = {"type": "directional_area", "id": "lamp", "radiance": radiance}
    emitter.update(profile or {"profile": "cosine_power", "exponent": exponent})
    scene = mi.load_dict({"type": "scene", "r": {
        "type": "rectangle", "emitter": emitter,
        "bsdf": {"type": "separable", "target_radiance": target, "normalization": normalization,
                 "emission": {"type": "ref", "id": "lamp"}}}}, optimize=False)
    _scenes.append(scene)
    return scene.shapes()[0].bsdf(), scene.emitters()[0]


def _frame_si(n, wi):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*wi)
    return si


@pytest.mark.parametrize("wi, profile", [
    ([0.0, 0.0, 1.0], None), ([0.6, 0.0, 0.8], None), ([0.95, 0.0, 0.3122], None),
    ([0.6, 0.0, 0.8], {"profile": "tabulated", "values": "0.2, 1.2, 1.8, 0.4"}),
    ([0.6, 0.0, 0.8], {"profile": "cosine_power", "exponent": 40.0})])
def test_separable_sampling_matches_pdf(wi, profile):
    bsdf, _ = separable_on_emitter(profile=profile)

    def sample_func(u):
        bs, _ = bsdf.sample(mi.BSDFContext(), _frame_si(dr.width(u), wi), u.x, mi.Point2f(u.y, u.z))
        return bs.wo

    def pdf_func(d):
        return bsdf.pdf(mi.BSDFContext(), _frame_si(dr.width(d), wi), d)

    assert chi2(sample_func, pdf_func)[0]
    assert not chi2(sample_func, lambda d: mi.warp.square_to_uniform_hemisphere_pdf(d))[0]


@pytest.mark.parametrize("profile", [{"profile": "cosine_power", "exponent": 3.0},
                                     {"profile": "tabulated", "values": "0.2, 1.2, 1.8, 0.4"}])
def test_separable_reciprocity_and_albedo(profile):
    bsdf, emitter = separable_on_emitter(profile=profile)
    ctx = mi.BSDFContext()
    a, b = _random_dirs(5000, 7), _random_dirs(5000, 8)
    si = _frame_si(5000, [0, 0, 1])
    si.wi = a
    f_ab = np.array(bsdf.eval(ctx, si, b) / mi.Frame3f.cos_theta(b))
    si.wi = b
    f_ba = np.array(bsdf.eval(ctx, si, a) / mi.Frame3f.cos_theta(a))
    assert np.allclose(f_ab, f_ba, rtol=1e-4)
    for theta_deg in (0, 40, 75):
        t = np.radians(theta_deg)
        wi = [float(np.sin(t)), 0.0, float(np.cos(t))]
        albedo = albedo_by_quadrature(bsdf, wi)
        le = 1.5 * np.array(emitter.profile_value(mi.Float(np.cos(t))))[0]
        assert np.allclose(albedo, 1.0 - le / 3.0, atol=2e-3), (theta_deg, albedo, 1 - le / 3)


def test_separable_without_emission_is_lambertian_with_albedo_one():
    scene = mi.load_dict({"type": "scene", "r": {"type": "rectangle",
                                                 "bsdf": {"type": "separable", "target_radiance": 3.0}}})
    _scenes.append(scene)
    bsdf = scene.shapes()[0].bsdf()
    assert np.allclose(albedo_by_quadrature(bsdf, [0.3, 0.0, 0.95]), 1.0, atol=1e-3)


def test_separable_simulated_normalization_has_the_predicted_jensen_bias():
    """The paper's random normalization puts X = pi (L~ - (2/M) sum Le(w_i) cos) in the
    denominator, so E[f] = f_exact * mu * E[1/X] > f_exact (Jensen). The BSDF must match
    that prediction, computed here independently with numpy (M = 16, Le = 1.5 cos^3)."""
    exact, _ = separable_on_emitter(normalization="exact")
    simulated, _ = separable_on_emitter(normalization="simulated")
    n = 400000
    si = _frame_si(n, [0.0, 0.0, 1.0])
    si.uv = mi.Point2f(dr.arange(mi.Float, n) / n, 0.0)    # fresh random numbers per lane
    wo = mi.Vector3f(0.0, 0.6, 0.8)
    fe = np.array(exact.eval(mi.BSDFContext(), si, wo))[0, 0]
    fs = np.array(simulated.eval(mi.BSDFContext(), si, wo))[0]
    measured = fs.mean() / fe - 1
    rng = np.random.default_rng(0)
    c = rng.random((200000, 16))                            # cos(theta) of uniform hemisphere directions
    x = np.pi * (3.0 - 2.0 * (1.5 * c ** 3 * c).mean(axis=1))
    mu = np.pi * (3.0 - 1.5 * 2 * np.pi / 5 / np.pi)        # pi L~ - integral of 1.5 cos^3 cos
    predicted = mu * np.mean(1.0 / x) - 1
    se = fs.std() / np.sqrt(n) / fe
    assert predicted > 0.001 and abs(measured - predicted) < 4 * se + 2e-4, (measured, predicted, se)


@pytest.mark.parametrize("kwargs, message", [
    (dict(target=1.0), "must exceed the maximum emission 1.5"),
    (dict(normalization="mc"), "normalization='mc' must be one of"),
])
def test_separable_bad_inputs(kwargs, message):
    with pytest.raises(Exception, match=message):
        separable_on_emitter(**kwargs)


def test_separable_refuses_another_shapes_emitter():
    scene = mi.load_dict({"type": "scene",
                          "a": {"type": "rectangle", "emitter": {"type": "directional_area", "id": "lamp_a"},
                                "bsdf": {"type": "diffuse"}},
                          "b": {"type": "rectangle", "bsdf": {"type": "separable", "target_radiance": 2.0,
                                                              "emission": {"type": "ref", "id": "lamp_a"}}}},
                         optimize=False)
    _scenes.append(scene)
    bsdf = scene.shapes()[1].bsdf()
    with pytest.raises(ValueError, match="must reference the emitter of the shape this BSDF sits on"):
        bsdf.eval(mi.BSDFContext(), _frame_si(1, [0, 0, 1]), mi.Vector3f(0, 0, 1))
    del bsdf, scene


def test_separable_without_reference_on_an_emitting_shape_is_refused():
    """A separable BSDF that forgot `emission` on a directional_area surface: loud error."""
    scene = mi.load_dict({"type": "scene",
                          "a": {"type": "rectangle", "emitter": {"type": "directional_area", "id": "lamp_a"},
                                "bsdf": {"type": "separable", "target_radiance": 2.0}}}, optimize=False)
    _scenes.append(scene)
    emitter = scene.emitters()[0]
    si = _frame_si(1, [0, 0, 1])
    with pytest.raises(ValueError, match="does not reference this emitter"):
        emitter.eval(si)
    del emitter, scene


@pytest.mark.parametrize("profile", [None, {"profile": "tabulated", "values": "0.2, 1.2, 1.8, 0.4"}])
def test_separable_importance_sampling_weight_is_the_albedo(profile):
    """Grey uniform emission: pdf proportional to (L~ - Le(w')) cos, so every sample
    weight f cos / pdf equals the albedo a(w) = 1 - Le(w)/L~ (up to the 2048-bin table)."""
    bsdf, emitter = separable_on_emitter(profile=profile)
    wi = [0.6, 0.0, 0.8]
    rng = np.random.default_rng(5)
    n = 20000
    bs, weight = bsdf.sample(mi.BSDFContext(), _frame_si(n, wi), mi.Float(rng.random(n)),
                             mi.Point2f(rng.random(n), rng.random(n)))
    w = np.array(weight)[0]
    albedo = 1.0 - 1.5 * float(np.array(emitter.profile_value(mi.Float(0.8)))[0]) / 3.0
    assert np.all(np.array(bs.pdf) > 0)
    assert abs(w.mean() - albedo) < 1e-3 and w.std() < 1e-2 * albedo, (w.mean(), w.std(), albedo)


def test_separable_with_textured_emission_samples_cosine_weighted():
    """Spatially varying emission: the fallback is cosine-weighted sampling (chi-square)."""
    scene = mi.load_dict({"type": "scene", "r": {
        "type": "rectangle",
        "emitter": {"type": "directional_area", "id": "lamp", "exponent": 2.0,
                    "radiance": {"type": "checkerboard", "color0": 0.5, "color1": 1.0}},
        "bsdf": {"type": "separable", "target_radiance": 3.0, "emission": {"type": "ref", "id": "lamp"}}}},
        optimize=False)
    _scenes.append(scene)
    bsdf = scene.shapes()[0].bsdf()
    wi = [0.6, 0.0, 0.8]

    def sample_func(u):
        return bsdf.sample(mi.BSDFContext(), _frame_si(dr.width(u), wi), u.x, mi.Point2f(u.y, u.z))[0].wo

    assert chi2(sample_func, lambda d: dr.maximum(d.z, 0.0) * dr.inv_pi)[0]
    del bsdf, scene
