"""The `phong` and `separable` BSDFs: values against independent closed forms written
here in numpy (Phong's f cos and pdf, eq. 9 of the separable BSDF), Phong's albedo at
normal incidence (kd + ks exactly), textures, the Jensen bias of the 'simulated'
normalization, sampling (chi-square), reciprocity, bad inputs; tests of the tests (a
Phong whose specular part is scaled by 0.5 or 0.9, a separable BSDF with a wrong
normalization integral) must fail the value tests by a wide margin."""
import contextlib
from unittest import mock

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

import budget


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

#: value checks: |plugin - numpy| <= RTOL |numpy| + ATOL * (peak of the function)
RTOL, ATOL = 1e-5, 1e-7


def phong_xml(n, kd=0.3, ks=0.6):
    return ('<float name="exponent" value="%g"/><rgb name="diffuse_reflectance" value="%g"/>'
            '<rgb name="specular_reflectance" value="%g"/>' % (n, kd, ks))


def chi2(sample_func, pdf_func, k):
    """Chi-square test (seed ``budget.seed(k)``) at the suite's level; (verdict, test).
    ires=16: with Mitsuba's default trapezoid rule (ires=4) the pdf's integral over the
    cells is off where it has edges or peaks (Phong n = 0 has a step at cos(alpha) = 0):
    p-values measured over 20 seeds, Phong n = 0: 1e-4, 2e-4, 7.8e-3 ... (12 seeds), far
    from uniform, so the test would fail a correct plugin well above its level; with
    ires=16 they are uniform (min 0.06 of 20; n = 10: min 0.05, n = 50: 0.013)."""
    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func, sample_dim=3,
                         ires=16, seed=budget.seed(k))
    return budget.chi2(test), test


def assert_rejected(verdict, test):
    """A test of the test: the chi-square test rejects, and not by a hair."""
    assert not verdict
    assert test.fail or test.p_value < 1e-20, (test.p_value, test.messages)


@pytest.mark.parametrize("n, wi, k", [(10, [0.3, 0.1, 0.9], 101), (2, [0.7, 0.0, 0.3], 102),
                                      (50, [0.0, 0.0, 1.0], 103), (0, [0.5, 0.5, 0.5], 104)])
def test_phong_sampling_matches_pdf(n, wi, k):
    sample_func, pdf_func = BSDFAdapter("phong", phong_xml(n), wi=dr.normalize(mi.ScalarVector3f(wi)))
    ok, test = chi2(sample_func, pdf_func, k)
    assert ok, test.messages


def test_chi2_rejects_a_wrong_pdf():
    wi = dr.normalize(mi.ScalarVector3f(0.3, 0.1, 0.9))
    sample_func, _ = BSDFAdapter("phong", phong_xml(10), wi=wi)
    _, wrong_pdf = BSDFAdapter("phong", phong_xml(14), wi=wi)   # pdf of another exponent
    assert_rejected(*chi2(sample_func, wrong_pdf, 105))


def _rgb(value):
    return value if isinstance(value, dict) else {"type": "rgb", "value": value}


def _phong(n=10, kd=0.3, ks=0.6):
    return mi.load_dict({"type": "phong", "exponent": float(n), "diffuse_reflectance": _rgb(kd),
                         "specular_reflectance": _rgb(ks)})


def _random_dirs(n, rng):
    return mi.warp.square_to_uniform_hemisphere(mi.Point2f(rng.random(n), rng.random(n)))


def test_phong_is_reciprocal():
    bsdf, ctx = _phong(), mi.BSDFContext()
    rng = budget.rng(106)
    a, b = _random_dirs(10000, rng), _random_dirs(10000, rng)
    si = dr.zeros(mi.SurfaceInteraction3f, 10000)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = a
    f_ab = bsdf.eval(ctx, si, b) / mi.Frame3f.cos_theta(b)
    si.wi = b
    f_ba = bsdf.eval(ctx, si, a) / mi.Frame3f.cos_theta(a)
    assert np.allclose(np.array(f_ab), np.array(f_ba), rtol=1e-4, atol=1e-6)


def albedo_by_quadrature(bsdf, wi, n=512):
    """a(wi) = integral of eval(wi, wo) dwo by the midpoint rule in (cos theta, phi).
    Measured error against n = 2048 for the BSDFs of the tests (phong n = 10,
    roughconductor alpha 0.3, diffuse): <= 1.2e-5."""
    iz, iphi = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(2 * n) + 0.5) / (2 * n), indexing="ij")
    z, phi = iz.ravel(), 2 * np.pi * iphi.ravel()
    r = np.sqrt(1 - z * z)
    wo = mi.Vector3f(r * np.cos(phi), r * np.sin(phi), z)
    si = dr.zeros(mi.SurfaceInteraction3f, z.size)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*wi)
    value = np.array(bsdf.eval(mi.BSDFContext(), si, wo))
    return value.mean(axis=1) * 2 * np.pi


#: bound of albedo_by_quadrature's error (measured <= 1.2e-5)
QUADRATURE_ERROR = 1e-4


@pytest.mark.parametrize("theta_deg, k", [(0, 107), (45, 108), (80, 109)])
def test_phong_albedo_at_most_kd_plus_ks_and_sample_weights_agree(theta_deg, k):
    bsdf = _phong(10, 0.3, 0.6)
    t = np.radians(theta_deg)
    wi = [float(np.sin(t)), 0.0, float(np.cos(t))]
    a = albedo_by_quadrature(bsdf, wi)
    assert np.all(a <= 0.9 + 1e-3) and np.all(a >= 0.3 - 1e-3)
    # the mean sample weight of sample() estimates the same albedo
    n = 200000
    rng = budget.rng(k)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*wi)
    _, w = bsdf.sample(mi.BSDFContext(), si, mi.Float(rng.random(n)), mi.Point2f(rng.random(n), rng.random(n)))
    w = np.array(w)
    budget.close(w.mean(axis=1), a, w.std(axis=1) / np.sqrt(n), slack=QUADRATURE_ERROR,
                 what="mean phong sample weight vs quadrature albedo")


@pytest.mark.parametrize("params, message", [
    ({"diffuse_reflectance": 0.7, "specular_reflectance": 0.5},
     r"phong: parameters diffuse_reflectance=0.7, specular_reflectance=0.5 are invalid together; valid range: "
     r"diffuse_reflectance \+ specular_reflectance <= 1 in every channel"),
    ({"exponent": -1.0}, r"phong: parameter exponent=-1.0 is invalid; valid range: a finite number >= 0"),
    ({"diffuse_reflectance": -0.1}, r"phong: parameter diffuse_reflectance=-0.1 is invalid; valid range: .*>= 0"),
])
def test_phong_bad_inputs(params, message):
    with pytest.raises(Exception, match=message):
        mi.load_dict(dict({"type": "phong"}, **params))


# ----------------------------------------------------------------------------- phong values
# The closed form, written independently of bsdfs/phong.py:
#   f cos = (kd/pi + ks (n+2)/(2 pi) cos^n(alpha)) cos(theta_o),
#   pdf   = P_d cos(theta_o)/pi + (1 - P_d) (n+1)/(2 pi) cos^n(alpha),  P_d = mean kd / (mean kd + mean ks)
# with alpha the angle between wo and the mirror direction (-wi.x, -wi.y, wi.z) of wi;
# the lobe is the hemisphere around the mirror direction (cos^n(alpha) = 0 where
# cos(alpha) <= 0, also for n = 0, as its sampling density (n+1)/(2 pi) cos^n normalises
# over that hemisphere), and everything is zero unless wi and wo are above the surface.

PHONG_CASES = {          # id: (kd, ks, n); kd + ks <= 1 per channel
    "grey_n10": (0.3, 0.6, 10.0),
    "n0": (0.5, 0.5, 0.0),
    "rgb_n3.5": ([0.1, 0.4, 0.7], [0.8, 0.5, 0.2], 3.5),
    "rgb_n1": ([0.6, 0.2, 0.0], [0.3, 0.1, 1.0], 1.0),
    "specular_only_n50": (0.0, 0.9, 50.0),
    "diffuse_only": (0.7, 0.0, 5.0),
}
# n <= 50: cos(alpha) is a float32 dot product (error ~1e-7), which cos^n amplifies n
# times; at n = 200 the plugin's relative error reaches 1.7e-5 (float32, not a bug).


def _channels(v, count):
    """(3, count) float64 array of an RGB value (scalar, triple or per-lane (3, count))."""
    v = np.asarray(v, dtype=np.float64)
    return np.broadcast_to(v.reshape(3, -1) if v.size >= 3 else v.reshape(1, 1), (3, count))


def phong_reference(kd, ks, n, wi, wo):
    """(f cos, pdf) of the modified Phong BSDF, numpy float64; wi, wo (3, N) local."""
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    count = wi.shape[1]
    kd, ks = _channels(kd, count), _channels(ks, count)
    above = (wi[2] > 0) & (wo[2] > 0)
    cos_alpha = -wi[0] * wo[0] - wi[1] * wo[1] + wi[2] * wo[2]
    lobe = np.where(cos_alpha > 0, np.abs(cos_alpha) ** n, 0.0)
    value = (kd / np.pi + ks * (n + 2) / (2 * np.pi) * lobe) * wo[2]
    md, ms = kd.mean(axis=0), ks.mean(axis=0)
    p_d = np.where(md + ms > 0, md / np.where(md + ms > 0, md + ms, 1.0), 1.0)
    pdf = p_d * wo[2] / np.pi + (1 - p_d) * (n + 1) / (2 * np.pi) * lobe
    return np.where(above, value, 0.0), np.where(above, pdf, 0.0)


def unit_vectors(rng, count):
    v = rng.normal(size=(3, count))
    return v / np.linalg.norm(v, axis=0)


def direction_pairs(rng, count):
    """float32 (wi, wo), (3, count) each: wi uniform on the sphere; wo uniform on the
    sphere for half the pairs, near the mirror direction of wi (spreads 0.01, 0.1, 0.3)
    for the other half, so that the specular peak is well covered."""
    wi, wo = unit_vectors(rng, count), unit_vectors(rng, count)
    m = count // 2
    mirror = np.array([-wi[0, :m], -wi[1, :m], wi[2, :m]])
    near = mirror + rng.normal(size=(3, m)) * rng.choice([0.01, 0.1, 0.3], size=m)
    wo[:, :m] = near / np.linalg.norm(near, axis=0)
    return wi.astype(np.float32), wo.astype(np.float32)


def local_si(wi, uv=None):
    """SurfaceInteraction3f with the identity shading frame, local wi (3, N), and uv."""
    count = wi.shape[1]
    si = dr.zeros(mi.SurfaceInteraction3f, count)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.n = mi.Vector3f(0, 0, 1)
    si.wi = mi.Vector3f(wi)
    if uv is not None:
        si.uv = mi.Point2f(uv)
    return si


def value_error(got, reference):
    """max |got - reference| / (RTOL |reference| + ATOL * peak): the value check passes at <= 1."""
    got, reference = np.asarray(got, np.float64), np.asarray(reference, np.float64)
    peak = max(float(np.max(np.abs(reference))), 1e-30)
    return float(np.max(np.abs(got - reference) / (RTOL * np.abs(reference) + ATOL * peak)))


def phong_errors(bsdf, kd, ks, n, k, count=20000, uv=None):
    """Normalised errors (<= 1 passes) of eval, pdf and eval_pdf of ``bsdf`` against
    phong_reference on ``count`` random direction pairs (seed k); kd, ks may be per-lane."""
    wi, wo = direction_pairs(budget.rng(k), count)
    si, ctx, d = local_si(wi, uv), mi.BSDFContext(), mi.Vector3f(wo)
    value, pdf = np.array(bsdf.eval(ctx, si, d)), np.array(bsdf.pdf(ctx, si, d))
    both = [np.array(x) for x in bsdf.eval_pdf(ctx, si, d)]
    ref_value, ref_pdf = phong_reference(kd, ks, n, wi, wo)
    cos_alpha = -wi[0] * wo[0] - wi[1] * wo[1] + wi[2] * wo[2]
    return dict(value=value_error(value, ref_value), pdf=value_error(pdf, ref_pdf[None]),
                eval_pdf=max(value_error(both[0], ref_value), value_error(both[1], ref_pdf[None])),
                nonzero=float(np.mean(ref_pdf > 0)),
                peak=int(np.sum((wi[2] > 0) & (wo[2] > 0) & (cos_alpha > 0.99))))


def check_phong_values(case, k):
    kd, ks, n = PHONG_CASES[case]
    err = phong_errors(_phong(n, kd, ks), kd, ks, n, k)
    assert err["nonzero"] > 0.25 and err["peak"] > 1000, err       # the test covers the lobe
    return err


@pytest.mark.parametrize("case", sorted(PHONG_CASES))
def test_phong_eval_and_pdf_match_the_closed_form(case):
    k = 110 + sorted(PHONG_CASES).index(case)
    err = check_phong_values(case, k)
    assert err["value"] <= 1 and err["pdf"] <= 1 and err["eval_pdf"] <= 1, err


def gauss_legendre(count, a=0.0, b=1.0):
    x, w = np.polynomial.legendre.leggauss(count)
    return 0.5 * (b - a) * x + 0.5 * (b + a), 0.5 * (b - a) * w


def phong_normal_albedo(bsdf, nodes=96, phis=16):
    """Albedo at normal incidence: integral of eval over the hemisphere, Gauss-Legendre
    in cos(theta) (exact for cos^n cos up to n = 190) times the midpoint rule in phi."""
    z, wz = gauss_legendre(nodes)
    phi = 2 * np.pi * (np.arange(phis) + 0.5) / phis
    z, phi = np.meshgrid(z, phi, indexing="ij")
    weight = np.repeat(wz, phis) * (2 * np.pi / phis)
    r = np.sqrt(1 - z.ravel() ** 2)
    wo = mi.Vector3f(r * np.cos(phi.ravel()), r * np.sin(phi.ravel()), z.ravel())
    si = local_si(np.array([[0.0], [0.0], [1.0]]).repeat(z.size, axis=1))
    return (np.array(bsdf.eval(mi.BSDFContext(), si, wo), dtype=np.float64) * weight).sum(axis=1)


ALBEDO_TOLERANCE = 1e-4


@pytest.mark.parametrize("case", sorted(PHONG_CASES))
def test_phong_albedo_at_normal_incidence_is_kd_plus_ks(case):
    """At normal incidence cos(alpha) = cos(theta_o), and the integral of cos^n cos over
    the hemisphere is 2 pi/(n + 2): the albedo is kd + ks exactly."""
    kd, ks, n = PHONG_CASES[case]
    albedo = phong_normal_albedo(_phong(n, kd, ks))
    exact = _channels(kd, 1)[:, 0] + _channels(ks, 1)[:, 0]
    assert np.all(np.abs(albedo - exact) <= ALBEDO_TOLERANCE), (albedo, exact)


def checkerboard(color0, color1, scale=1.0):
    def color(c):   # RGB, not limited to [0, 1] (a radiance may exceed 1)
        return {"type": "srgb", "color": _channels(c, 1)[:, 0].tolist(), "unbounded": True}
    return {"type": "checkerboard", "color0": color(color0), "color1": color(color1),
            "to_uv": mi.ScalarTransform4f().scale([scale, scale, 1.0])}


def checkerboard_reference(color0, color1, uv, scale=1.0):
    """Mitsuba's checkerboard: color0 where floor(2 s u) + floor(2 s v) is even, color1 elsewhere."""
    odd = (np.floor(2 * scale * uv[0]) + np.floor(2 * scale * uv[1])) % 2 == 1
    return np.where(odd, _channels(color1, 1), _channels(color0, 1))


def cell_interior_uv(rng, count, scale=1.0, margin=1e-3):
    """float32 uv (2, count) at least ``margin`` away from every checkerboard cell edge."""
    uv = rng.random((2, 4 * count))
    frac = (2 * scale * uv) % 1.0
    keep = np.all((frac > margin) & (frac < 1 - margin), axis=0)
    return uv[:, keep][:, :count].astype(np.float32)


TEXTURED_KD = ([0.1, 0.5, 0.3], [0.45, 0.05, 0.2])      # checkerboard colors of kd
TEXTURED_KS = ([0.5, 0.4, 0.6], [0.2, 0.45, 0.1])       # of ks, at three times the frequency


def check_textured_phong(k, n=6.0, count=20000):
    bsdf = _phong(n, checkerboard(*TEXTURED_KD), checkerboard(*TEXTURED_KS, scale=3.0))
    uv = cell_interior_uv(budget.rng(k), count, scale=3.0)
    kd = checkerboard_reference(*TEXTURED_KD, uv)
    ks = checkerboard_reference(*TEXTURED_KS, uv, scale=3.0)
    err = phong_errors(bsdf, kd, ks, n, k + 1, count=count, uv=uv)
    # every combination of the two textures' colors occurs
    assert len({(a, b) for a, b in zip(kd[0], ks[0])}) == 4
    return err


def test_phong_eval_uses_the_texture_values_at_the_point():
    """kd and ks given as checkerboard textures: eval and pdf use the texture values at
    the point's uv (checkerboard written in numpy)."""
    err = check_textured_phong(130)
    assert err["value"] <= 1 and err["pdf"] <= 1 and err["eval_pdf"] <= 1, err


@contextlib.contextmanager
def phong_with_scaled_specular(scale):
    """A broken Phong: the specular part of f cos multiplied by ``scale`` (pdf untouched)."""
    cls = type(_phong())
    original = cls._value_and_pdf
    zero = mi.load_dict({"type": "uniform", "value": 0.0})

    def value_and_pdf(self, ctx, si, wo, active):
        value, pdf = original(self, ctx, si, wo, active)
        kd, self.kd = self.kd, zero
        try:
            specular, _ = original(self, ctx, si, wo, active)
        finally:
            self.kd = kd
        return value - (1.0 - scale) * specular, pdf

    with mock.patch.object(cls, "_value_and_pdf", value_and_pdf):
        yield


@pytest.mark.parametrize("scale", [0.5, 0.9])
def test_phong_value_tests_catch_a_scaled_specular_part(scale):
    """Test of the tests: constant-radiance scenes pass for any BSDF, so only these value
    tests see a specular part scaled by 0.5 or 0.9. Each fails by a wide margin (the pdf
    is untouched by this sabotage, and its check keeps passing)."""
    with phong_with_scaled_specular(scale):
        for case in sorted(PHONG_CASES):
            kd, ks, n = PHONG_CASES[case]
            err = check_phong_values(case, 110 + sorted(PHONG_CASES).index(case))
            albedo = phong_normal_albedo(_phong(n, kd, ks))
            kd3, ks3 = _channels(kd, 1)[:, 0], _channels(ks, 1)[:, 0]
            # the sabotage is measured exactly: albedo kd + scale ks
            assert np.all(np.abs(albedo - (kd3 + scale * ks3)) <= ALBEDO_TOLERANCE), (case, albedo)
            assert err["pdf"] <= 1, (case, err)
            if np.max(ks3) == 0:
                continue                                   # no specular part to scale
            assert err["value"] > 1000, (case, err)        # > 1000 x the tolerance
            assert np.max(np.abs(albedo - (kd3 + ks3))) > 500 * ALBEDO_TOLERANCE, (case, albedo)
            with pytest.raises(AssertionError):
                test_phong_eval_and_pdf_match_the_closed_form(case)
            with pytest.raises(AssertionError):
                test_phong_albedo_at_normal_incidence_is_kd_plus_ks(case)
        assert check_textured_phong(130)["value"] > 1000
        with pytest.raises(AssertionError):
            test_phong_eval_uses_the_texture_values_at_the_point()


# ----------------------------------------------------------------------------- separable


def separable_on_emitter(target=3.0, exponent=3.0, radiance=1.5, normalization="exact", profile=None, samples=None):
    emitter = {"type": "directional_area", "id": "lamp", "radiance": radiance}
    emitter.update(profile or {"profile": "cosine_power", "exponent": exponent})
    bsdf = {"type": "separable", "target_radiance": target, "normalization": normalization,
            "emission": {"type": "ref", "id": "lamp"}}
    if samples is not None:
        bsdf["samples"] = samples
    scene = mi.load_dict({"type": "scene", "r": {"type": "rectangle", "emitter": emitter, "bsdf": bsdf}},
                         optimize=False)
    _scenes.append(scene)
    return scene.shapes()[0].bsdf(), scene.emitters()[0]


def _frame_si(n, wi):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    si.wi = mi.Vector3f(*wi)
    return si


# ------------------------------------------------------------- emission profiles, in numpy
def profile_reference(profile, cos_theta):
    """profile(cos theta) of a directional_area profile dict, numpy float64: cos^n, or the
    table's values uniformly spaced over theta in [0, pi/2], linear in theta."""
    c = np.clip(np.asarray(cos_theta, np.float64), 0.0, 1.0)
    if profile.get("profile", "cosine_power") == "cosine_power":
        return c ** profile.get("exponent", 1.0)
    values = [float(v) for v in profile["values"].replace(",", " ").split()]
    return np.interp(np.arccos(c), np.linspace(0.0, np.pi / 2, len(values)), values)


def profile_cos_integral(profile):
    """Integral of profile * cos over the hemisphere: 2 pi/(n + 2) for cos^n; for a table,
    2 pi integral of p(theta) cos sin dtheta by 32-point Gauss-Legendre per table segment
    (p is linear there, the integrand smooth)."""
    if profile.get("profile", "cosine_power") == "cosine_power":
        return 2 * np.pi / (profile.get("exponent", 1.0) + 2)
    k = len(profile["values"].replace(",", " ").split())
    edges = np.linspace(0.0, np.pi / 2, k)
    total = 0.0
    for a, b in zip(edges[:-1], edges[1:]):
        t, w = gauss_legendre(32, a, b)
        total += np.sum(w * profile_reference(profile, np.cos(t)) * np.cos(t) * np.sin(t))
    return 2 * np.pi * total


def separable_reference(target, radiance, profile, wi, wo):
    """Eq. 9 times cos(theta_o), numpy float64: (L~ - Le(wi)) (L~ - Le(wo)) cos(theta_o) /
    (L~ (pi L~ - radiance * integral profile cos)), zero unless wi and wo are above the
    surface; ``radiance`` may be per lane (3, N); profile None: no emission, f = 1/pi."""
    wi, wo = np.asarray(wi, np.float64), np.asarray(wo, np.float64)
    count = wi.shape[1]
    above = (wi[2] > 0) & (wo[2] > 0)
    if profile is None:
        return np.where(above, wo[2] / np.pi, 0.0)[None].repeat(3, axis=0)
    t, r = _channels(target, count), _channels(radiance, count)
    le_i, le_o = r * profile_reference(profile, wi[2]), r * profile_reference(profile, wo[2])
    f = (t - le_i) * (t - le_o) / (t * (np.pi * t - r * profile_cos_integral(profile)))
    return np.where(above, f * wo[2], 0.0)


COS3 = {"profile": "cosine_power", "exponent": 3.0}
TABLE = {"profile": "tabulated", "values": "0.2, 1.2, 1.8, 0.4"}
SEPARABLE_CASES = {     # id: (target, radiance, profile); target > max emission
    "cos3": (3.0, 1.5, COS3),
    "rgb_cos0.5": ([2.0, 2.5, 3.2], [0.5, 1.0, 1.5], {"profile": "cosine_power", "exponent": 0.5}),
    "cos40_target_near_max": (1.1, 1.0, {"profile": "cosine_power", "exponent": 40.0}),
    "cos0": (2.0, 1.0, {"profile": "cosine_power", "exponent": 0.0}),
    "table": (3.0, 1.5, TABLE),
    "rgb_table7": ([2.1, 2.5, 3.0], [0.9, 0.4, 1.0], {"profile": "tabulated",
                                                      "values": "1, 0.5, 2, 0.1, 1.3, 0.7, 1.9"}),
    "checkerboard_cos2": (3.0, "checkerboard", {"profile": "cosine_power", "exponent": 2.0}),
}
RADIANCE_CHECKER = ([0.5, 0.8, 1.1], [1.4, 0.3, 2.0])       # colors of the textured radiance


def check_separable_values(case, k, count=20000):
    target, radiance, profile = SEPARABLE_CASES[case]
    rng = budget.rng(k)
    uv = None
    if radiance == "checkerboard":
        uv = cell_interior_uv(rng, count)
        bsdf, _ = separable_on_emitter(target, radiance=checkerboard(*RADIANCE_CHECKER), profile=profile)
        radiance = checkerboard_reference(*RADIANCE_CHECKER, uv)
    else:
        bsdf, _ = separable_on_emitter(target, radiance=_rgb(radiance), profile=profile)
    wi, wo = direction_pairs(rng, count)
    value = np.array(bsdf.eval(mi.BSDFContext(), local_si(wi, uv), mi.Vector3f(wo)))
    reference = separable_reference(target, radiance, profile, wi, wo)
    assert np.mean(reference[0] > 0) > 0.25
    return value_error(value, reference)


@pytest.mark.parametrize("case", sorted(SEPARABLE_CASES))
def test_separable_eval_matches_eq9(case):
    """eval() = eq. 9 times cos(theta_o), with the normalization integral in closed form
    (cos^n) or by quadrature (tabulated, linear in theta), RGB and textured emission."""
    err = check_separable_values(case, 140 + sorted(SEPARABLE_CASES).index(case))
    assert err <= 1, err


def test_separable_eq9_test_catches_a_wrong_normalization_integral():
    """Test of the test: an emitter whose integral of cos^n cos is 2 pi/(n + 1) (the cosine
    forgotten) makes eq. 9's normalization 6 % off (cos^3, L~ = 3, Le = 1.5)."""
    _, emitter = separable_on_emitter()
    cls = type(emitter)
    with mock.patch.object(cls, "hemispherical_integral_ad", lambda self: 2 * np.pi / (self.exponent + 1)):
        err = check_separable_values("cos3", 140 + sorted(SEPARABLE_CASES).index("cos3"))
    assert err > 1000, err


@pytest.mark.parametrize("wi, profile, k", [
    ([0.0, 0.0, 1.0], None, 160), ([0.6, 0.0, 0.8], None, 161), ([0.95, 0.0, 0.3122], None, 162),
    ([0.6, 0.0, 0.8], {"profile": "tabulated", "values": "0.2, 1.2, 1.8, 0.4"}, 163),
    ([0.6, 0.0, 0.8], {"profile": "cosine_power", "exponent": 40.0}, 164)])
def test_separable_sampling_matches_pdf(wi, profile, k):
    bsdf, _ = separable_on_emitter(profile=profile)

    def sample_func(u):
        bs, _ = bsdf.sample(mi.BSDFContext(), _frame_si(dr.width(u), wi), u.x, mi.Point2f(u.y, u.z))
        return bs.wo

    def pdf_func(d):
        return bsdf.pdf(mi.BSDFContext(), _frame_si(dr.width(d), wi), d)

    ok, test = chi2(sample_func, pdf_func, k)
    assert ok, test.messages
    # test of the test: the cosine-weighted density (the fallback for textured emission)
    # is not the importance density (L~ - Le(w')) cos
    assert_rejected(*chi2(sample_func, lambda d: dr.maximum(d.z, 0.0) * dr.inv_pi, k + 10))


@pytest.mark.parametrize("profile, k", [(COS3, 170), (TABLE, 171)])
def test_separable_reciprocity_and_albedo(profile, k):
    bsdf, emitter = separable_on_emitter(profile=profile)
    ctx = mi.BSDFContext()
    rng = budget.rng(k)
    a, b = _random_dirs(5000, rng), _random_dirs(5000, rng)
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
        le = 1.5 * profile_reference(profile, np.cos(t))
        assert np.allclose(albedo, 1.0 - le / 3.0, atol=2e-3), (theta_deg, albedo, 1 - le / 3)


def test_separable_without_emission_is_lambertian_with_albedo_one():
    scene = mi.load_dict({"type": "scene", "r": {"type": "rectangle",
                                                 "bsdf": {"type": "separable", "target_radiance": 3.0}}})
    _scenes.append(scene)
    bsdf = scene.shapes()[0].bsdf()
    assert np.allclose(albedo_by_quadrature(bsdf, [0.3, 0.0, 0.95]), 1.0, atol=1e-3)
    wi, wo = direction_pairs(budget.rng(172), 20000)
    value = np.array(bsdf.eval(mi.BSDFContext(), local_si(wi), mi.Vector3f(wo)))
    assert value_error(value, separable_reference(3.0, 0.0, None, wi, wo)) <= 1


def jensen_prediction(m, rng, count=1 << 20):
    """(predicted relative bias, its SE) of the 'simulated' normalization for Le = 1.5 cos^3,
    L~ = 3, M = m, numpy: E[f] / f_exact - 1 = mu E[1/X] - 1 with X = pi L~ - (2 pi/M)
    sum Le(w_i) cos(theta_i), w_i uniform on the hemisphere (cos(theta_i) uniform in
    [0, 1]), mu = pi L~ - 1.5 * 2 pi/5."""
    c = rng.random((count, m))
    x = np.pi * 3.0 - 2 * np.pi * (1.5 * c ** 4).mean(axis=1)
    mu = np.pi * 3.0 - 1.5 * 2 * np.pi / 5
    ratio = mu / x
    return ratio.mean() - 1, ratio.std() / np.sqrt(count)


def simulated_bias(m, k, n=400000):
    """(measured relative bias of the 'simulated' normalization at M = m, its SE), from
    n independent evaluations (Le = 1.5 cos^3, L~ = 3)."""
    exact, _ = separable_on_emitter(normalization="exact")
    simulated, _ = separable_on_emitter(normalization="simulated", samples=m)
    si = _frame_si(n, [0.0, 0.0, 1.0])
    si.uv = mi.Point2f(dr.arange(mi.Float, n) / n, 0.0)    # fresh random numbers per lane ...
    si.p = mi.Point3f(float(budget.seed(k)), 0.0, 0.0)      # ... and per seed offset
    wo = mi.Vector3f(0.0, 0.6, 0.8)
    fe = np.array(exact.eval(mi.BSDFContext(), si, wo))[0, 0]
    fs = np.array(simulated.eval(mi.BSDFContext(), si, wo))[0]
    return fs.mean() / fe - 1, fs.std() / np.sqrt(n) / fe


def test_separable_simulated_normalization_has_the_predicted_jensen_bias():
    """The paper's random normalization puts X = pi (L~ - (2/M) sum Le(w_i) cos) in the
    denominator, so E[f] = f_exact * mu * E[1/X] > f_exact (Jensen), a bias that shrinks
    with M. The BSDF must match that prediction, computed here independently with numpy
    (Le = 1.5 cos^3), at M = 4 (+3.5 %) and M = 16 (+0.72 %)."""
    measured = {}
    for m, k in ((4, 180), (16, 181)):
        bias, se = simulated_bias(m, k)
        predicted, se_predicted = jensen_prediction(m, budget.rng(k))
        budget.close(bias, predicted, np.hypot(se, se_predicted), slack=2e-5,
                     what="relative Jensen bias at M=%d" % m)
        assert predicted > 20 * np.hypot(se, se_predicted), (m, predicted, se, se_predicted)   # resolved
        measured[m] = bias, se
    # M is used: the bias at M = 4 is ~5x the one at M = 16, far outside the noise
    (b4, se4), (b16, se16) = measured[4], measured[16]
    assert b4 - b16 > 20 * np.hypot(se4, se16), measured


@pytest.mark.parametrize("kwargs, message", [
    (dict(target=1.0), "separable: parameters target_radiance=1.0, emission=<DirectionalAreaEmitter id='lamp'> are "
                       "invalid together; valid range: target_radiance must exceed the maximum emission 1.5"),
    (dict(normalization="mc"), "separable: parameter normalization='mc' is invalid; valid range: one of 'exact', "
                               "'simulated'"),
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
    with pytest.raises(ValueError, match="separable: parameter emission=<DirectionalAreaEmitter id='lamp_a'> is "
                                         "invalid; valid range: a reference to the emitter of the shape this BSDF "
                                         "sits on"):
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


@pytest.mark.parametrize("profile, k", [(None, 190), (TABLE, 191)])
def test_separable_importance_sampling_weight_is_the_albedo(profile, k):
    """Grey uniform emission: pdf proportional to (L~ - Le(w')) cos, so every sample
    weight f cos / pdf equals the albedo a(w) = 1 - Le(w)/L~ (up to the 2048-bin table)."""
    bsdf, emitter = separable_on_emitter(profile=profile)
    wi = [0.6, 0.0, 0.8]
    rng = budget.rng(k)
    n = 20000
    bs, weight = bsdf.sample(mi.BSDFContext(), _frame_si(n, wi), mi.Float(rng.random(n)),
                             mi.Point2f(rng.random(n), rng.random(n)))
    w = np.array(weight)[0]
    albedo = 1.0 - 1.5 * float(profile_reference(profile or COS3, 0.8)) / 3.0
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

    ok, test = chi2(sample_func, lambda d: dr.maximum(d.z, 0.0) * dr.inv_pi, 192)
    assert ok, test.messages
    del bsdf, scene


# ------------------------------------------------------------ the context's lobe selection
def _context(type_mask=None, component=None):
    ctx = mi.BSDFContext()
    if type_mask is not None:
        ctx.type_mask = int(type_mask)
    if component is not None:
        ctx.component = component
    return ctx


def test_phong_honours_the_contexts_lobe_selection():
    """As Mitsuba's BSDFs: a context selecting the diffuse lobe (by type or as component
    0) gets kd/pi cos and cosine samples of weight kd; the glossy lobe (component 1) the
    rest; neither lobe: nothing. Before, phong ignored the selection (test of the test:
    the full BSDF differs from each lobe)."""
    bsdf = mi.load_dict({"type": "phong", "diffuse_reflectance": 0.3, "specular_reflectance": 0.6, "exponent": 10.0})
    wi, wo = direction_pairs(budget.rng(180), 4000)
    si = local_si(wi)
    full = np.array(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo)))
    diffuse = 0.3 / np.pi * np.maximum(wo[2], 0)[None] * (wi[2] > 0)[None]
    for ctx in (_context(mi.BSDFFlags.DiffuseReflection), _context(component=0)):
        value = np.array(bsdf.eval(ctx, si, mi.Vector3f(wo)))
        assert np.allclose(value, np.broadcast_to(diffuse, value.shape), rtol=1e-5, atol=1e-7)
        bs, w = bsdf.sample(ctx, si, mi.Float(budget.rng(181).random(4000)), mi.Point2f(budget.rng(182).random((2, 4000))))
        ok = np.array(bs.pdf) > 0
        assert ok.mean() > 0.3 and np.all(np.array(bs.sampled_type)[ok] == int(mi.BSDFFlags.DiffuseReflection))
        assert np.allclose(np.array(w)[:, ok], 0.3, rtol=1e-4)
    glossy = np.array(bsdf.eval(_context(component=1), si, mi.Vector3f(wo)))
    assert np.allclose(glossy + np.broadcast_to(diffuse, glossy.shape), full, rtol=1e-5, atol=1e-7)
    assert np.abs(glossy - full).max() > 1e-3 and np.abs(glossy).max() > 1e-3
    none = _context(mi.BSDFFlags.DeltaReflection)
    assert np.all(np.array(bsdf.eval(none, si, mi.Vector3f(wo))) == 0)
    assert np.all(np.array(bsdf.pdf(none, si, mi.Vector3f(wo))) == 0)


def test_separable_honours_the_contexts_lobe_selection():
    scene = mi.load_dict({"type": "scene", "r": {"type": "rectangle",
                                                 "bsdf": {"type": "separable", "target_radiance": 3.0}}})
    _scenes.append(scene)
    bsdf = scene.shapes()[0].bsdf()
    wi, wo = direction_pairs(budget.rng(183), 1000)
    si = local_si(wi)
    on = np.array(bsdf.eval(_context(mi.BSDFFlags.DiffuseReflection), si, mi.Vector3f(wo)))
    assert np.abs(on).max() > 0.1
    for ctx in (_context(mi.BSDFFlags.GlossyReflection), _context(component=1)):
        assert np.all(np.array(bsdf.eval(ctx, si, mi.Vector3f(wo))) == 0)
        bs, w = bsdf.sample(ctx, si, mi.Float(0.5), mi.Point2f(0.3, 0.6))
        assert np.all(np.array(bs.pdf) == 0) and np.all(np.array(w) == 0)
