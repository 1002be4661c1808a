"""Exact values of the analytic cases against independent hand computations."""
import numpy as np
import pytest

from mi_plugins.verify import analytic
from mi_plugins.verify.analytic.classic import default_sphere_emission


def test_furnace_value_and_truncation():
    case = analytic.furnace(albedo=0.5, emission=0.5, geometry="box")
    assert np.allclose(case.expected(-1), 1.0)
    assert np.allclose(case.expected(1), 0.5)            # emitters only
    assert np.allclose(case.expected(2), 0.5 * 1.5)
    assert np.allclose(case.expected(3), 0.5 * 1.75)
    assert case.expected().shape == (32, 32, 3)


def test_furnace_rgb_values():
    case = analytic.furnace(albedo=[0.2, 0.5, 0.8], emission=[1.0, 0.5, 0.2], geometry="sphere")
    assert np.allclose(case.expected(-1)[0, 0], [1.0 / 0.8, 0.5 / 0.5, 0.2 / 0.2])


def test_keller_cube_is_one_half():
    assert np.allclose(analytic.keller_cube().expected(), 0.5)


def test_mirror_sphere_value():
    case = analytic.mirror_sphere(reflectance=0.75, emission=0.25)
    assert np.allclose(case.expected(-1), 1.0)
    assert np.allclose(case.expected(2), 0.25 * 1.75)


def test_bekaert_is_one_and_has_no_truncated_value():
    case = analytic.bekaert("sierpinski")
    assert np.allclose(case.expected(-1), 1.0)
    with pytest.raises(ValueError, match="only max_depth=-1"):
        case.expected(3)


def _bilinear_repeat(tex, u, v):
    """Independent bilinear lookup with repeat wrapping (texel centres at (i + 1/2)/n)."""
    h, w = tex.shape[:2]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    t = lambda yy, xx: tex[yy % h, xx % w]
    return ((1 - fy) * ((1 - fx) * t(y0, x0) + fx * t(y0, x0 + 1)) + fy * ((1 - fx) * t(y0 + 1, x0) + fx * t(y0 + 1, x0 + 1)))


def test_diffuse_sphere_mean_emission_by_independent_quadrature():
    tex = default_sphere_emission().astype(np.float64)
    n = 2000
    theta = (np.arange(n) + 0.5) / n * np.pi              # midpoint rule in theta, weight sin(theta)
    phi = (np.arange(2 * n) + 0.5) / (2 * n)
    u, v = np.meshgrid(phi, theta / np.pi)
    le = _bilinear_repeat(tex, u, v)
    w = np.sin(theta)[:, None, None]
    mean = (le * w).sum(axis=(0, 1)) / (w.sum() * 2 * n)
    case = analytic.diffuse_sphere(albedo=0.5)
    assert np.allclose(case.mean_emission, mean, rtol=2e-4)


def test_diffuse_sphere_constant_emission_reduces_to_furnace():
    case = analytic.diffuse_sphere(albedo=0.6, emission=0.4)
    assert np.allclose(case.expected(-1), 0.4 / 0.4, rtol=1e-5)
    assert np.allclose(case.expected(2), 0.4 + 0.4 * 0.6, rtol=1e-5)


def test_diffuse_sphere_image_varies_and_truncation_adds_E_a_k():
    case = analytic.diffuse_sphere(albedo=0.5)
    e1, e2, e3, einf = (case.expected(d) for d in (1, 2, 3, -1))
    assert e1.std() > 0.05                                 # off-centre camera: non-trivial image
    E = case.mean_emission
    assert np.allclose(e2 - e1, E * 0.5, atol=1e-5)
    assert np.allclose(e3 - e2, E * 0.25, atol=1e-5)
    assert np.allclose(einf - e1, E * 1.0, atol=1e-5)


@pytest.mark.parametrize("factory, message", [
    (lambda: analytic.furnace(albedo=1.0), "albedo=1.0 is outside"),
    (lambda: analytic.furnace(albedo=[0.5, 1.2, 0.5]), "albedo"),
    (lambda: analytic.furnace(emission=-0.1), "emission=-0.1 is outside"),
    (lambda: analytic.furnace(geometry="torus"), "geometry='torus'"),
    (lambda: analytic.mirror_sphere(reflectance=1.5), "reflectance=1.5 is outside"),
    (lambda: analytic.diffuse_sphere(albedo=-0.2), "albedo=-0.2"),
    (lambda: analytic.diffuse_sphere(radius=0), "radius=0"),
    (lambda: analytic.furnace(resolution=0), "resolution=0"),
])
def test_invalid_parameters_are_named(factory, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace("[", r"\[")):
        factory()


def test_cases_registry_builds_every_case():
    table = analytic.cases()
    for name in ("furnace_box", "furnace_sierpinski", "keller_cube", "bekaert_box", "diffuse_sphere",
                 "mirror_sphere"):
        assert name in table
    for name, factory in table.items():
        case = factory(resolution=8)
        assert case.expected().shape == (8, 8, 3)


def test_mesh_diffuse_sphere_mean_emission_from_the_loaded_meshes():
    import mitsuba as mi
    from mi_plugins.patches.meshtable import MeshTable
    case = analytic.diffuse_sphere(albedo=0.5, geometry="sphere_mesh")
    scene = case.scene()
    table = MeshTable(scene, "test")
    weighted = np.zeros(3)
    for k, shape in enumerate(table.meshes):
        si = mi.SurfaceInteraction3f(shape.sample_position(0.0, mi.Point2f(0.3, 0.6)), mi.Color0f())
        si.wi = mi.Vector3f(0, 0, 1)
        le = np.array(shape.emitter().eval(si)).ravel()[:3]
        weighted += le * table.areas_np[table.shape_index_np == k].sum()
    assert np.allclose(case.mean_emission, weighted / table.total_area, rtol=1e-5)
    assert not case.exact and case.known_bias > 0


def test_mesh_diffuse_sphere_passes_path_with_its_stated_tolerance():
    case = analytic.diffuse_sphere(albedo=0.5, geometry="sphere_mesh", resolution=16)
    res = analytic.check(case, {"type": "path", "max_depth": 2}, spp=128, runs=16, bias=case.known_bias)
    assert res.passed, res
