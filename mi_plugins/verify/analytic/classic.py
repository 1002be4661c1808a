"""The classic analytic cases: furnace, Keller's cube, Bekaert, diffuse and mirror sphere.

Exact values (from the analytic-scenes paper of Szirmay-Kalos, Kovács and Abbas), with Mitsuba's
``max_depth`` convention (D = 1: emitters only; D = -1: unbounded):

- furnace:        L = Le * sum_{k<D} a^k  ->  Le / (1 - a)
- bekaert:        L = 1 (albedo a(x), emission 1 - a(x)); only D = -1 is exact
- diffuse sphere: L(x) = Le(x) + E * sum_{1<=k<D} a^k  ->  Le(x) + E a / (1 - a),
                  E = area mean of Le over the sphere (paper section 3.1)
- mirror sphere:  L = Le * sum_{k<D} k_r^k  ->  Le / (1 - k_r)   (paper section 3.2)

Their derivatives w.r.t. the albedo, reflectance and emission follow term by term
(``case.derivatives``; d/dx sum_{k<D} x^k = sum_{k<D} k x^(k-1) -> 1 / (1 - x)^2).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.verify import geometry as geo
from .case import (AnalyticCase, camera_for, closed_surfaces, require_range, rgb, rgb_dict,
                   truncated_geometric, truncated_geometric_derivative as geometric_derivative)

#: Bekaert checkerboard albedos (RGB) of the two cells; emission is 1 - albedo.
BEKAERT_ALBEDO = ((0.2, 0.5, 0.8), (0.7, 0.35, 0.1))


class ConstantCase(AnalyticCase):
    """A case whose exact radiance is the same at every point and direction."""

    def __init__(self, name, surfaces, camera, value_fn, truncation_exact=True, **kw):
        super().__init__(name, surfaces, camera, **kw)
        self._value_fn = value_fn
        self.truncation_exact = truncation_exact

    def exact_constant(self, max_depth=-1):
        if max_depth is not None and max_depth >= 0 and not self.truncation_exact:
            raise ValueError("%s: only max_depth=-1 has an exact value (got max_depth=%d)"
                             % (self.name, max_depth))
        return self._value_fn(max_depth)

    def expected_derivative(self, name, max_depth=-1, supersampling=None):
        self.derivative(name)
        self.exact_constant(max_depth)  # refuses the depths without an exact value
        return super().expected_derivative(name, max_depth, supersampling)


def furnace_derivatives(case, a, le):
    """dL/da and dL/dLe of a furnace (albedo ``a``, emission ``le``; moved on every surface)."""
    case.add_derivative("albedo", "bsdf.reflectance.value", lambda d: le * geometric_derivative(a, d),
                        formula="dL/da = Le sum_{k<D} k a^(k-1) -> Le / (1 - a)^2")
    case.add_derivative("emission", "emitter.radiance.value", lambda d: truncated_geometric(a, d),
                        formula="dL/dLe = sum_{k<D} a^k -> 1 / (1 - a)")
    return case


def furnace(albedo=0.5, emission=0.5, geometry="box", resolution=32, **geometry_options):
    """Constant diffuse albedo a and diffuse emission Le everywhere: L = Le / (1 - a).

    albedo in [0, 1) per channel; emission >= 0 per channel.
    """
    a = require_range(albedo, "albedo", 0.0, 1.0, hi_open=True,
                      what="range of contractive albedos (L = Le/(1-a) diverges at a = 1)")
    le = require_range(emission, "emission", 0.0, None, what="range of physical emission")
    surfaces = closed_surfaces(geometry, {"type": "diffuse", "reflectance": rgb_dict(a)},
                               {"type": "area", "radiance": rgb_dict(le)}, **geometry_options)
    case = ConstantCase("furnace_" + geometry, surfaces, camera_for(geometry),
                        lambda d: le * truncated_geometric(a, d), resolution=resolution,
                        params=dict(albedo=albedo, emission=emission, geometry=geometry),
                        description="diffuse albedo %s, emission %s: L = Le/(1-a)" % (albedo, emission))
    return furnace_derivatives(case, a, le)


def keller_cube(resolution=32):
    """Keller's empty cube (12 triangles, rho = 1/2, L0 = 1/4): L = 1/2."""
    case = furnace(albedo=0.5, emission=0.25, geometry="box", resolution=resolution)
    case.name = "keller_cube"
    case.description = "Keller's cube: rho = 1/2, Le = 1/4, L = 1/2"
    return case


def _bekaert_textures():
    """Nearest-filtered 4 x 4 RGB checkerboards of albedo a(x) and emission 1 - a(x)."""
    a0, a1 = (np.array(c, dtype=np.float32) for c in BEKAERT_ALBEDO)
    checker = (np.add.outer(np.arange(4), np.arange(4)) % 2)[..., None]
    albedo = np.where(checker == 0, a0, a1).astype(np.float32)
    tex = lambda arr: {"type": "bitmap", "bitmap": mi.Bitmap(arr), "filter_type": "nearest", "raw": True}
    return tex(albedo), tex((1.0 - albedo).astype(np.float32))


def bekaert(geometry="box", resolution=32, **geometry_options):
    """Spatially varying albedo a(x) with emission 1 - a(x) everywhere: L = 1.

    On meshes, alternating cells (box faces, triangles) get the two RGB albedos of
    ``BEKAERT_ALBEDO`` (piecewise constant, exact for finite-element methods too); on
    the analytic sphere a 4 x 4 RGB checkerboard texture does the same.
    """
    if geometry == "sphere":
        albedo, emission = _bekaert_textures()
        surfaces = closed_surfaces(geometry, {"type": "diffuse", "reflectance": albedo},
                                   {"type": "area", "radiance": emission})
    else:
        surfaces = geo.surfaces(geometry, pattern=True, **geometry_options)
        for key, shape in surfaces.items():
            a = np.array(BEKAERT_ALBEDO[int(key[-1])])
            shape["bsdf"] = {"type": "diffuse", "reflectance": rgb_dict(a)}
            shape["emitter"] = {"type": "area", "radiance": rgb_dict(1.0 - a)}
    return ConstantCase("bekaert_" + geometry, surfaces, camera_for(geometry), lambda d: np.ones(3),
                        truncation_exact=False, resolution=resolution, params=dict(geometry=geometry),
                        description="piecewise albedo a(x), emission 1 - a(x): L = 1")


def default_sphere_emission():
    """Smooth RGB emission texture (6 x 8 texels, constant polar rows) for the diffuse sphere."""
    v = (np.arange(6)[:, None] + 0.5) / 6
    u = (np.arange(8)[None, :] + 0.5) / 8
    r = 0.6 + 0.5 * np.sin(np.pi * v) * np.cos(2 * np.pi * u)
    g = 0.4 + 0.3 * np.sin(np.pi * v) * np.sin(4 * np.pi * u)
    b = 0.2 + 0.8 * v * (1 - v) + 0.0 * u
    tex = np.stack([r, g, b], axis=-1)
    tex[0, :] = tex[0, :].mean(axis=0)   # constant polar rows keep Le continuous at the poles
    tex[-1, :] = tex[-1, :].mean(axis=0)
    return tex.astype(np.float32)


class DiffuseSphereCase(AnalyticCase):
    """Inside a sphere: L(x) = Le(x) + E * sum_{1<=k<D} a^k (exact for the analytic sphere).

    ``mean_emission`` is E; ``exact`` is False for the tessellated sphere, where the
    formula is the sphere limit and the mesh adds a discretisation bias.
    """

    def __init__(self, name, surfaces, camera, albedo, mean_emission, exact=True, **kw):
        super().__init__(name, surfaces, camera, **kw)
        self.albedo = albedo
        self.mean_emission = mean_emission
        self.exact = exact

    def exact_at(self, si, ray, max_depth, scene):
        if max_depth == 0:
            return dr.zeros(mi.Color3f, dr.width(si.p))
        le = si.emitter(scene).eval(si)          # Le(x) exactly as Mitsuba evaluates it
        bounces = truncated_geometric(self.albedo, max_depth) - 1.0
        return mi.Color3f(le) + mi.Color3f(*[float(v) for v in self.mean_emission * bounces])

    def add_albedo_derivative(self, bias=0.0):
        """dL/da = E sum_{1<=k<D} k a^(k-1): the same everywhere (Le(x) does not depend on a)."""
        return self.add_derivative("albedo", "bsdf.reflectance.value",
                                   lambda d: self.mean_emission * geometric_derivative(self.albedo, d), bias=bias,
                                   formula="dL/da = E sum_{1<=k<D} k a^(k-1) -> E / (1 - a)^2")


def _emission_texture_dict(emission):
    if np.ndim(emission) >= 2:
        tex = np.asarray(emission, dtype=np.float32)
        if tex.ndim == 2:
            tex = np.repeat(tex[..., None], 3, axis=2)
        if tex.ndim != 3 or tex.shape[2] != 3 or np.any(tex < 0) or not np.all(np.isfinite(tex)):
            raise ValueError("emission: a texture must be a finite, non-negative (H, W) or (H, W, 3) "
                             "array (got shape %s)" % (np.shape(emission),))
        return {"type": "bitmap", "bitmap": mi.Bitmap(tex), "filter_type": "bilinear",
                "wrap_mode": "repeat", "raw": True}
    return rgb_dict(require_range(emission, "emission", 0.0, None, what="range of physical emission"))


def sphere_area_mean(texture, n=(1024, 2048)):
    """Area mean of a texture over the unit sphere with Mitsuba's sphere uv mapping
    (u = phi / 2pi, v = theta / pi): midpoint rule in (u, cos theta)."""
    nz, nu = n
    iz, iu = np.meshgrid((np.arange(nz) + 0.5) / nz, (np.arange(nu) + 0.5) / nu, indexing="ij")
    z = 1.0 - 2.0 * iz
    si = dr.zeros(mi.SurfaceInteraction3f, nz * nu)
    si.uv = mi.Point2f(mi.Float(iu.ravel()), mi.Float(np.arccos(z).ravel() / np.pi))
    value = texture.eval(si)
    return np.array(value, dtype=np.float64).reshape(3, -1).mean(axis=1)


#: tolerance for the sphere-limit value on the geodesic sphere (see diffuse_sphere)
MESH_SPHERE_BIAS = 3e-4

#: tolerance for the sphere-limit derivative dL/da on the geodesic sphere: measured at a = 0.5
#: (16 x 16 px, 16 runs) -2e-5 +- 3e-4 at full depth (prb_basic, max_depth 30, 512 spp) and
#: -1.9e-4 +- 8e-5 at max_depth 2 (direct_projective, 1024 spp), of dL/da = 1.85 and 0.46
MESH_SPHERE_DERIVATIVE_BIAS = 1e-3

#: RGB emission levels of the tessellated diffuse sphere (one shape per level)
MESH_SPHERE_LEVELS = ((1.2, 0.3, 0.2), (0.2, 0.9, 0.4), (0.3, 0.3, 1.1), (0.9, 0.8, 0.1), (0.05, 0.05, 0.05))


def _mesh_sphere_levels(mesh):
    """Emission level of every triangle: bands in latitude and longitude of its centroid."""
    c = mesh.vertices[mesh.faces].mean(axis=1)
    theta = np.arccos(np.clip(c[:, 2] / np.linalg.norm(c, axis=1), -1, 1))
    phi = np.arctan2(c[:, 1], c[:, 0]) % (2 * np.pi)
    return (np.floor(theta / np.pi * 3).astype(int) + np.floor(phi / (2 * np.pi) * 4).astype(int)) \
        % len(MESH_SPHERE_LEVELS)


def _diffuse_mesh_sphere(a, subdivisions):
    """Geodesic sphere whose triangles emit one of MESH_SPHERE_LEVELS (one shape per level)."""
    mesh = geo.icosphere(subdivisions)
    levels = _mesh_sphere_levels(mesh)
    areas = mesh.face_areas()
    surfaces, weighted = {}, np.zeros(3)
    for k, le in enumerate(MESH_SPHERE_LEVELS):
        mask = levels == k
        if not mask.any():
            continue
        shape = geo.mesh_shape(mesh.subset(mask), "icosphere%d_level%d" % (subdivisions, k))
        shape["bsdf"] = {"type": "diffuse", "reflectance": rgb_dict(a)}
        shape["emitter"] = {"type": "area", "radiance": rgb_dict(le)}
        surfaces["sphere_%d" % k] = shape
        weighted += np.array(le) * areas[mask].sum()
    return surfaces, weighted / areas.sum()


def diffuse_sphere(albedo=0.5, emission=None, radius=1.0, resolution=32, geometry="sphere", subdivisions=3):
    """Inside a sphere of ``radius`` with constant diffuse albedo and spatially varying
    diffuse emission Le(x): L(x) = Le(x) + E a / (1 - a), E = area mean of Le (paper 3.1).

    ``geometry='sphere'`` (default): Mitsuba's analytic sphere, exact; ``emission`` is a
    float, RGB or (H, W[, 3]) texture array (default: a smooth RGB bitmap).
    ``geometry='sphere_mesh'``: a unit geodesic sphere (``subdivisions``) whose triangles
    emit piecewise-constant RGB levels (``MESH_SPHERE_LEVELS``; E is their exact area
    mean); the formula is then the sphere limit, not exact for the polyhedron
    (``case.exact`` is False): finite-element tests state their tolerance explicitly.
    """
    a = require_range(albedo, "albedo", 0.0, 1.0, hi_open=True,
                      what="range of contractive albedos (the sphere response diverges at a = 1)")
    if geometry == "sphere_mesh":
        if emission is not None or radius != 1.0:
            raise ValueError("diffuse_sphere(geometry='sphere_mesh') has fixed per-triangle emission levels "
                             "and unit radius; emission and radius apply to geometry='sphere' only")
        surfaces, mean = _diffuse_mesh_sphere(a, int(subdivisions))
        case = DiffuseSphereCase("diffuse_sphere_mesh", surfaces, camera_for("sphere_mesh"), a, mean, exact=False,
                                 resolution=resolution, params=dict(albedo=albedo, geometry=geometry,
                                                                    subdivisions=subdivisions),
                                 description="albedo %s, per-triangle emission levels (E = %s): sphere-limit "
                                 "value L = Le(x) + E a/(1-a)" % (albedo, np.array2string(mean, precision=4)))
        # Emission jumps between triangles: finer pixel quadrature (error <= jump / 96 at edges).
        case.supersampling = 48
        # Measured with `path` (4096 spp x 8 runs, 16 x 16 px): the image mean of the
        # 1280-triangle sphere deviates from the sphere limit by -7e-5 +- 6e-5 (a = 0.5,
        # full depth) and 2e-5 +- 2e-5 (max_depth 2); 80 triangles: 3e-5 +- 8e-5.
        case.known_bias = MESH_SPHERE_BIAS
        return case.add_albedo_derivative(MESH_SPHERE_DERIVATIVE_BIAS)
    if geometry != "sphere":
        raise ValueError("geometry=%r: diffuse_sphere supports 'sphere' (exact) and 'sphere_mesh'" % (geometry,))
    r = float(require_range(radius, "radius", 0.0, None, lo_open=True, what="range")[0])
    emission = default_sphere_emission() if emission is None else emission
    radiance = _emission_texture_dict(emission)
    surfaces = closed_surfaces("sphere", {"type": "diffuse", "reflectance": rgb_dict(a)},
                               {"type": "area", "radiance": radiance})
    surfaces["sphere"]["radius"] = r
    mean = sphere_area_mean(mi.load_dict(radiance))
    case = DiffuseSphereCase("diffuse_sphere", surfaces, camera_for("sphere", r), a, mean,
                             resolution=resolution,
                             params=dict(albedo=albedo, radius=r, emission="texture" if np.ndim(emission) >= 2
                                         else emission),
                             description="albedo %s, textured emission (E = %s): L = Le(x) + E a/(1-a)"
                             % (albedo, np.array2string(mean, precision=4)))
    return case.add_albedo_derivative()


class MirrorSphereCase(AnalyticCase):
    """Inside an emitting ideal mirror sphere: L(theta) = Le(theta) * sum_{j<D} k^j."""

    def __init__(self, name, surfaces, camera, reflectance, diffuse_emission=None, **kw):
        super().__init__(name, surfaces, camera, **kw)
        self.reflectance = reflectance
        self.diffuse_emission = diffuse_emission

    def exact_constant(self, max_depth=-1):
        if self.diffuse_emission is None:
            return None
        return self.diffuse_emission * truncated_geometric(self.reflectance, max_depth)

    def exact_at(self, si, ray, max_depth, scene):
        # The emission leaving the hit towards the camera, at the angle theta it has there;
        # each mirror bounce returns the same angle (paper section 3.2).
        le = si.emitter(scene).eval(si)
        return le * mi.Color3f(*[float(v) for v in truncated_geometric(self.reflectance, max_depth)])

    def add_derivatives(self, radiance=None):
        """dL/dk = Le(theta) sum_{j<D} j k^(j-1); dL/dR = Le(theta) / R sum_{j<D} k^j for the emitter's
        constant RGB radiance R (diffuse emission: Le = R; directional: Le(theta) = R profile(theta))."""
        k, le, key = self.reflectance, self.diffuse_emission, "bsdf.specular_reflectance.value"
        if le is None:
            color = lambda v: mi.Color3f(*[float(x) for x in v])
            self.add_derivative("reflectance", key, formula="dL/dk = Le(theta) sum_{j<D} j k^(j-1) -> Le(theta) / "
                                "(1 - k)^2", at=lambda si, ray, d, scene: si.emitter(scene).eval(si)
                                * color(geometric_derivative(k, d)))
            if radiance is not None and np.all(radiance > 0):
                self.add_derivative("emission", "emitter.radiance", formula="dL/dR = Le(theta) / R sum_{j<D} k^j "
                                    "-> Le(theta) / (R (1 - k))", at=lambda si, ray, d, scene:
                                    si.emitter(scene).eval(si) * color(truncated_geometric(k, d) / radiance))
            return self
        self.add_derivative("reflectance", key, lambda d: le * geometric_derivative(k, d),
                            formula="dL/dk = Le sum_{j<D} j k^(j-1) -> Le / (1 - k)^2")
        return self.add_derivative("emission", "emitter.radiance.value", lambda d: truncated_geometric(k, d),
                                   formula="dL/dLe = sum_{j<D} k^j -> 1 / (1 - k)")

    def not_applicable(self, integrator):
        if integrator.get("type") == "ptracer":
            return ("a light tracer cannot connect light paths to a pinhole camera through an ideal "
                    "mirror (every light path reflected by the mirror has zero probability of reaching it)")
        return None


def mirror_sphere(reflectance=0.5, emission=0.5, resolution=32):
    """Inside an ideal mirror sphere of reflectance k that also emits: L = Le / (1 - k)
    (paper section 3.2). ``emission``: a float/RGB (diffuse emission), or the dict of an
    isotropic ``directional_area`` emitter (Le(theta)): then L(theta) = Le(theta) / (1 - k),
    varying over the image because the camera is off-centre."""
    k = require_range(reflectance, "reflectance", 0.0, 1.0, hi_open=True,
                      what="range of contractive mirror reflectances")
    bsdf = {"type": "conductor", "material": "none", "specular_reflectance": rgb_dict(k)}
    if isinstance(emission, dict):
        if emission.get("type") != "directional_area":
            raise ValueError("emission=%r: a dict must describe a 'directional_area' emitter" % (emission,))
        surfaces = closed_surfaces("sphere", bsdf, emission)
        label = "%s profile" % emission.get("profile", "cosine_power")
        case = MirrorSphereCase("mirror_sphere_directional", surfaces, camera_for("sphere"), k,
                                resolution=resolution, params=dict(reflectance=reflectance, emission=emission),
                                description="ideal mirror k = %s, emission %s: L(theta) = Le(theta)/(1-k)"
                                % (reflectance, label))
        radiance = emission.get("radiance", 1.0)
        if isinstance(radiance, dict):  # a constant RGB radiance has a closed-form derivative, a texture not
            radiance = radiance.get("value") if radiance.get("type") == "rgb" else None
        return case.add_derivatives(None if radiance is None else rgb(radiance, "radiance"))
    le = require_range(emission, "emission", 0.0, None, what="range of physical emission")
    surfaces = closed_surfaces("sphere", bsdf, {"type": "area", "radiance": rgb_dict(le)})
    case = MirrorSphereCase("mirror_sphere", surfaces, camera_for("sphere"), k, diffuse_emission=le,
                            resolution=resolution, params=dict(reflectance=reflectance, emission=emission),
                            description="ideal mirror k = %s, emission %s: L = Le/(1-k)" % (reflectance, emission))
    return case.add_derivatives()


#: name -> factory(resolution=...) of the cases in the verification matrix
MATRIX_CASES = {
    "furnace_box": lambda **kw: furnace(0.5, 0.5, "box", **kw),
    "furnace_sphere": lambda **kw: furnace(0.5, 0.5, "sphere", **kw),
    "furnace_sphere_mesh": lambda **kw: furnace(0.5, 0.5, "sphere_mesh", **kw),
    "furnace_sierpinski": lambda **kw: furnace(0.5, 0.5, "sierpinski", **kw),
    "keller_cube": lambda **kw: keller_cube(**kw),
    "bekaert_box": lambda **kw: bekaert("box", **kw),
    "bekaert_sphere": lambda **kw: bekaert("sphere", **kw),
    "bekaert_sierpinski": lambda **kw: bekaert("sierpinski", **kw),
    "diffuse_sphere": lambda **kw: diffuse_sphere(0.5, **kw),
    "diffuse_sphere_mesh": lambda **kw: diffuse_sphere(0.5, geometry="sphere_mesh", **kw),
    "mirror_sphere": lambda **kw: mirror_sphere(0.5, 0.5, **kw),
    "mirror_sphere_cos4": lambda **kw: mirror_sphere(
        0.6, {"type": "directional_area", "profile": "cosine_power", "exponent": 4.0,
              "radiance": {"type": "rgb", "value": [0.8, 0.5, 0.3]}}, **kw),
}

#: the subset of `mi-plugins verify --quick`
QUICK_CASES = ("furnace_box", "furnace_sphere", "keller_cube", "bekaert_sierpinski", "diffuse_sphere",
               "mirror_sphere")
