"""Constant-radiance cases of the analytic-scenes paper, section 2.

BRDF testing (section 2.1): every surface of a closed scene gets the BSDF under
test and a ``simulated_area`` emitter Le = L~ (1 - a(x, w)) (albedo estimated
afresh at each evaluation, unbiased): the radiance is L~ everywhere, for ANY BSDF;
so is it in lightsource testing (section 2.2), hence dL/dL~ = 1 (L~ moved on every surface).
"""
import numpy as np

from .case import camera_for, closed_surfaces, require_range, rgb, rgb_dict
from .classic import ConstantCase, furnace_derivatives

#: the paper's section 4 set-up: Sierpinski scene, average albedo 0.47, Phong n = 10
PAPER_ALBEDO = 0.47
PAPER_PHONG = {"type": "phong", "diffuse_reflectance": {"type": "rgb", "value": [0.30, 0.30, 0.30]},
               "specular_reflectance": {"type": "rgb", "value": [0.17, 0.17, 0.17]}, "exponent": 10.0}


def constant_radiance_brdf(bsdf, target_radiance=1.0, geometry="box", samples=1, estimator="uniform",
                           resolution=32, name=None):
    """Every surface: the BSDF dict ``bsdf`` and a ``simulated_area`` emitter with
    target L~: the exact radiance is L~ everywhere and in every direction."""
    target = require_range(target_radiance, "target_radiance", 0.0, None, lo_open=True,
                           what="range of target radiances")
    if not isinstance(bsdf, dict) or "type" not in bsdf:
        raise ValueError("bsdf=%r: must be a Mitsuba BSDF dict with a 'type'" % (bsdf,))
    emitter = {"type": "simulated_area", "target_radiance": rgb_dict(target), "samples": int(samples),
               "estimator": estimator}
    surfaces = closed_surfaces(geometry, bsdf, emitter)
    case = ConstantCase(name or "constant_brdf_%s_%s" % (bsdf["type"], geometry), surfaces, camera_for(geometry),
                        lambda d: _constant_only(target, d), truncation_exact=False, resolution=resolution,
                        params=dict(bsdf=bsdf["type"], target_radiance=target_radiance, geometry=geometry,
                                    samples=samples, estimator=estimator),
                        description="BSDF %s with simulated emission (M=%d, %s): L = L~"
                        % (bsdf["type"], samples, estimator))
    return target_derivative(case, "emitter.target_radiance")


def _constant_only(target, max_depth):
    return np.array(target, dtype=np.float64)


def target_derivative(case, key):
    """dL/dL~ = 1: the target radiance ``key`` (of every surface's emitter or BSDF) moved together."""
    return case.add_derivative("target_radiance", key, lambda d: np.ones(3), formula="dL/dL~ = 1")


def sierpinski_diffuse_exact(resolution=32):
    """Paper section 4, case 1: diffuse albedo 0.47 with the exact emission 1 - 0.47: L = 1."""
    a = PAPER_ALBEDO
    surfaces = closed_surfaces("sierpinski", {"type": "diffuse", "reflectance": rgb_dict(a)},
                               {"type": "area", "radiance": rgb_dict(1.0 - a)})
    case = ConstantCase("sierpinski_diffuse_exact", surfaces, camera_for("sierpinski"),
                        lambda d: np.ones(3), truncation_exact=False, resolution=resolution,
                        params=dict(albedo=a), description="diffuse 0.47, exact emission 0.53: L = 1")
    return furnace_derivatives(case, rgb(a, "albedo"), rgb(1.0 - a, "emission"))  # a furnace: L = Le / (1 - a)


def sierpinski_diffuse_simulated(resolution=32):
    """Paper section 4, case 2: diffuse albedo 0.47 with simulated emission (M = 1): L = 1."""
    return constant_radiance_brdf({"type": "diffuse", "reflectance": rgb_dict(PAPER_ALBEDO)}, 1.0, "sierpinski",
                                  samples=1, resolution=resolution, name="sierpinski_diffuse_simulated")


def sierpinski_phong_simulated(resolution=32):
    """Paper section 4, case 3: Phong (kd 0.30 + ks 0.17, n = 10) with simulated emission (M = 1): L = 1."""
    return constant_radiance_brdf(dict(PAPER_PHONG), 1.0, "sierpinski", samples=1, resolution=resolution,
                                  name="sierpinski_phong_simulated")


#: name -> factory(resolution=...) of this module's cases in the verification matrix
MATRIX_CASES = {
    "constant_brdf_diffuse_sphere": lambda **kw: constant_radiance_brdf(
        {"type": "diffuse", "reflectance": rgb_dict([0.2, 0.5, 0.8])}, 1.0, "sphere", **kw),
    "constant_brdf_phong_box": lambda **kw: constant_radiance_brdf(dict(PAPER_PHONG), 1.0, "box", **kw),
    "constant_brdf_roughconductor_box": lambda **kw: constant_radiance_brdf(
        {"type": "roughconductor", "alpha": 0.3}, 1.0, "box", estimator="bsdf", **kw),
    "constant_brdf_roughplastic_sierpinski": lambda **kw: constant_radiance_brdf(
        {"type": "roughplastic", "alpha": 0.2}, 1.0, "sierpinski", **kw),
    "sierpinski_diffuse_exact": sierpinski_diffuse_exact,
    "sierpinski_diffuse_simulated": sierpinski_diffuse_simulated,
    "sierpinski_phong_simulated": sierpinski_phong_simulated,
}
QUICK_CASES = ("sierpinski_phong_simulated",)

__all__ = ["constant_radiance_brdf", "sierpinski_diffuse_exact", "sierpinski_diffuse_simulated",
           "sierpinski_phong_simulated"]


def constant_radiance_lightsource(emitters, target_radiance=2.0, geometry="sierpinski", normalization="exact",
                                  resolution=32, name=None):
    """Lightsource testing (paper section 2.2): every surface gets a ``separable`` BSDF
    for target L~; the surfaces named in ``emitters`` ({surface: directional_area dict})
    emit, the others do not: the exact radiance is L~ everywhere.

    Surface names are those of ``mi_plugins.verify.geometry.surfaces(geometry, pattern=True)``:
    e.g. 'walls_0', 'walls_1', 'sierpinski_0', 'sierpinski_1' (alternating cells), or
    'sphere' for the analytic sphere.
    """
    target = require_range(target_radiance, "target_radiance", 0.0, None, lo_open=True,
                           what="range of target radiances")
    surfaces = _geometry_surfaces(geometry)
    unknown = sorted(set(emitters) - set(surfaces))
    if unknown:
        raise ValueError("emitters: unknown surface(s) %s of geometry %r; its surfaces are %s"
                         % (", ".join(unknown), geometry, ", ".join(sorted(surfaces))))
    for key, shape in surfaces.items():
        bsdf = {"type": "separable", "target_radiance": rgb_dict(target), "normalization": normalization}
        if key in emitters:
            emitter = dict(emitters[key])
            if emitter.get("type") != "directional_area":
                raise ValueError("emitters[%r]: must be a 'directional_area' dict" % key)
            emitter["id"] = key + "_emission"
            shape["emitter"] = emitter
            bsdf["emission"] = {"type": "ref", "id": emitter["id"]}
        shape["bsdf"] = bsdf
    case = ConstantCase(name or "constant_lightsource_%s" % geometry, surfaces, camera_for(geometry),
                        lambda d: _constant_only(target, d), truncation_exact=False, resolution=resolution,
                        params=dict(emitters=sorted(emitters), target_radiance=target_radiance, geometry=geometry,
                                    normalization=normalization),
                        description="separable BSDFs, directional emitters on %s: L = L~" % ", ".join(sorted(emitters)))
    return target_derivative(case, "bsdf.target_radiance")


def _geometry_surfaces(geometry):
    from mi_plugins.verify import geometry as geo
    if geometry == "sphere":
        return geo.surfaces("sphere")
    return geo.surfaces(geometry, pattern=True)


def _lightsource_sierpinski(**kw):
    return constant_radiance_lightsource(
        {"walls_0": {"type": "directional_area", "profile": "cosine_power", "exponent": 3.0,
                     "radiance": {"type": "rgb", "value": [1.5, 1.0, 0.5]}},
         "sierpinski_1": {"type": "directional_area", "profile": "tabulated", "values": "0.2, 1.2, 1.8, 0.4",
                          "radiance": {"type": "rgb", "value": [0.6, 0.9, 1.0]}}},
        2.0, "sierpinski", **kw)


def _lightsource_box(**kw):
    return constant_radiance_lightsource(
        {"walls_1": {"type": "directional_area", "exponent": 1.0, "radiance": {"type": "rgb", "value": 1.2}}},
        1.5, "box", **kw)


MATRIX_CASES["constant_lightsource_sierpinski"] = _lightsource_sierpinski
MATRIX_CASES["constant_lightsource_box"] = _lightsource_box
__all__.append("constant_radiance_lightsource")
