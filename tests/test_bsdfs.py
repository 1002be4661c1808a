"""The `phong` BSDF: sampling (chi-square), reciprocity, energy, bad inputs."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # mitsuba.chi2 writes chi2_data.py on rejection


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
