"""One row per feature Mitsuba can put in a scene: every plugin the Mitsuba wheel ships
(BSDFs, emitters, shapes, sensors, films, reconstruction filters, textures, media, phase
functions, volumes, samplers, integrators), the film's pixel formats and a few cases
that are not plugins (an emitter facing a surface 1 cm away, negative emission, an open
scene with many emitters, finite depths).

A :class:`Row` builds a small scene with its feature on :func:`stage.stage`. The table of
plugins is not written by hand: :func:`mi_plugins.verify.coverage.catalog.mitsuba_plugins`
enumerates the wheel's ``plugins`` folder, and a plugin without a row here fails the
suite's catalogue test.
"""
from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from mi_plugins.verify.conformance.meshes import area, block, diffuse, quad, shape
from mi_plugins.verify.conformance.scene_library import sky_bitmap
from mi_plugins.verify.coverage import files
from mi_plugins.verify.coverage.gap_rows import gap_rows
from mi_plugins.verify.coverage.mesh_rows import mesh_rows
from mi_plugins.verify.coverage.stage import camera, film, light, look_at, stage, subject_transform


@dataclass
class Row:
    """``key`` ('kind:name'), the Mitsuba plugin it covers (None for a case), its
    ``build(resolution)`` (a scene dict; the integrator is added per cell),
    ``reference`` (Mitsuba integrator type the cells are compared with), ``na`` (a reason:
    no cell of the row can be built here), ``wrap`` (the row's feature is an integrator
    wrapping the tested one), ``max_depth`` (the depth of every cell; None: -1),
    ``reference_scene`` (the reference renders this scene instead, e.g. with the
    ``independent`` sampler where the row's sampler is the feature), ``reference_runs``
    (its runs where not the matrix's default: a row whose reference's spread sets the
    cells' power)."""
    key: str
    plugin: str = None
    build: object = None
    reference: str = "path"
    na: str = None
    wrap: object = None
    max_depth: int = None
    reference_scene: object = None
    spp_scale: float = 1.0
    reference_runs: int = None
    params: dict = field(default_factory=dict)   # given to every cell's integrator and to the reference
    note: str = ""
    tags: tuple = field(default_factory=tuple)

    @property
    def kind(self):
        return self.key.split(":", 1)[0]


def rgb(value):
    v = [float(value)] * 3 if np.isscalar(value) else [float(x) for x in value]
    return {"type": "rgb", "value": v}


def bitmap(values, raw=False):
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(values, dtype=np.float32)), "raw": raw,
            "filter_type": "bilinear"}


def noise(shape, seed, lo=0.0, hi=1.0):
    return lo + (hi - lo) * np.random.default_rng(seed).random(shape)


def cube_mesh():
    return block((0.0, 0.35, 0.0), (0.35, 0.35, 0.35), 2)


# ------------------------------------------------------------------ BSDFs (on the subject)
def _bsdf_rows():
    bump = bitmap(noise((16, 16, 1), 1), raw=True)
    normals = noise((8, 8, 3), 2, 0.35, 0.65)
    normals[..., 2] = 0.95
    b = {
        "diffuse": diffuse(0.5),
        "roughconductor": {"type": "roughconductor", "material": "Au", "alpha": 0.3},
        "conductor": {"type": "conductor", "material": "Cu"},
        "plastic": {"type": "plastic", "diffuse_reflectance": rgb(0.4)},
        "roughplastic": {"type": "roughplastic", "alpha": 0.2, "diffuse_reflectance": rgb(0.4)},
        "pplastic": {"type": "pplastic", "diffuse_reflectance": rgb(0.4), "alpha": 0.2},
        "dielectric": {"type": "dielectric", "int_ior": 1.5},
        "roughdielectric": {"type": "roughdielectric", "int_ior": 1.5, "alpha": 0.2},
        "thindielectric": {"type": "thindielectric", "int_ior": 1.5},
        "null": {"type": "null"},
        "mask": {"type": "mask", "opacity": 0.5, "bsdf": diffuse(0.6)},
        "twosided": {"type": "twosided", "bsdf": diffuse(0.6)},
        "blendbsdf": {"type": "blendbsdf", "weight": 0.4, "bsdf_0": diffuse(0.6),
                      "bsdf_1": {"type": "roughconductor", "material": "Al", "alpha": 0.3}},
        "bumpmap": {"type": "bumpmap", "arg": bump, "scale": 0.5, "bsdf": diffuse(0.6)},
        "normalmap": {"type": "normalmap", "normalmap": bitmap(normals, raw=True), "bsdf": diffuse(0.6)},
        "principled": {"type": "principled", "base_color": rgb([0.6, 0.4, 0.3]), "roughness": 0.5,
                       "metallic": 0.3},
        "principledthin": {"type": "principledthin", "base_color": rgb([0.6, 0.4, 0.3]), "roughness": 0.5,
                           "spec_trans": 0.4},
        "hair": {"type": "hair", "eumelanin": 0.3, "pheomelanin": 0.2},
        "polarizer": {"type": "polarizer"},
        "retarder": {"type": "retarder"},
        "circular": {"type": "circular"},
    }
    # the mask's reference is volpath: Mitsuba 3.9.1's path renders the light-sampled direct
    # light of mask surfaces too dark (docs/findings.md)
    # the rough glass floats 1 cm above the floor: resting on it, its bottom face and the floor
    # coincide and each integrator's ray offsets decide what passes between them (against
    # ptracer: path -0.3 %, qmc_lighttrace -1.3 %; at 1 cm all four within 0.2 %)
    floating = {"roughdielectric": 0.01}
    rows = [Row("bsdf:" + name, name, (lambda r, d=d, up=floating.get(name, 0.0): stage(r, subject={
                "type": "cube", "to_world": mi.ScalarTransform4f().translate([0, up, 0]) @ subject_transform(),
                "bsdf": d})), reference="volpath" if name == "mask" else "path") for name, d in b.items()]
    # twosided matters where a back side is lit: a panel whose front faces away from the camera
    rows.append(Row("case:twosided_panel", None, lambda r: stage(r, subject=shape(
        quad((0.0, 0.6, 0.1), (0.45, 0, 0), (0, 0.35, 0.35)), "coverage_panel",
        {"type": "twosided", "bsdf": diffuse(0.6)})), note="a panel lit on its front, seen from behind"))
    rows += [Row("bsdf:measured", "measured", na="needs a measured BRDF file of the RGL database; Mitsuba ships "
                                                 "none (the integrators treat it as any non-diffuse BSDF)"),
             Row("bsdf:measured_polarized", "measured_polarized",
                 na="Mitsuba refuses it outside spectral variants; the package renders RGB variants")]
    return rows


# ------------------------------------------------------------------ emitters
def _emitter_rows():
    spot_at = look_at((0.3, 2.0, 0.8), (0.0, 0.2, 0.0))
    e = {
        "area": light(),
        "point": {"type": "point", "position": [0.4, 1.8, 0.6], "intensity": rgb([3.0, 2.6, 2.2])},
        "spot": {"type": "spot", "to_world": spot_at, "cutoff_angle": 35.0, "beam_width": 25.0,
                 "intensity": rgb([8.0, 7.0, 6.0])},
        "projector": {"type": "projector", "to_world": spot_at, "fov": 50.0, "scale": 6.0,
                      "irradiance": bitmap(noise((8, 8, 3), 3, 0.2, 1.0))},
        "directional": {"type": "directional", "direction": [0.3, -1.0, -0.4], "irradiance": rgb([1.5, 1.4, 1.2])},
        "constant": {"type": "constant", "radiance": rgb([0.8, 0.85, 0.9])},
        "envmap": {"type": "envmap", "bitmap": sky_bitmap(),
                   "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], 70).rotate([1, 0, 0], 25)},
        "sunsky": {"type": "sunsky", "sun_scale": 0.0, "sky_scale": 1.0},
        "directionalarea": shape(quad((0.0, 2.2, 0.2), (0.35, 0, 0), (0, 0, 0.35)), "coverage_dirarea",
                                 diffuse(0.0), {"type": "directionalarea", "radiance": rgb(3.0)}),
    }
    rows = [Row("emitter:" + name, name, (lambda r, d=d: stage(r, emitter=d)),
                reference="ptracer" if name == "directionalarea" else "path") for name, d in e.items()]
    rows.append(Row("emitter:timed_sunsky", "timed_sunsky", na=(
        "Mitsuba 3.9.1's own path fails on it in the RGB variants (jit_var_schedule: not permitted, during the "
        "render): there is no reference (docs/findings/timed_sunsky_symbolic_any.py)")))
    # the stage light textured, on an analytic shape and on a sphere
    rows.append(Row("case:textured_area_sphere", None, lambda r: stage(r, emitter={
        "type": "sphere", "center": [0.2, 1.9, 0.3], "radius": 0.2, "bsdf": diffuse(0.0),
        "emitter": {"type": "area", "radiance": bitmap(noise((8, 16, 3), 4, 1.0, 8.0))}}), reference_runs=16))
    rows += _textured_light_rows()
    return rows


def textured_rectangle(radiance, flipped, center=(0.0, 2.2, 0.2), size=0.35):
    """A ``rectangle`` light facing down with a textured ``radiance``: wound upward and
    turned with ``flip_normals`` (``flipped``), or wound downward with its texture mirrored
    in v: the same radiance at every point and in every direction, the reference of the
    flipped one (Mitsuba 3.9.1 samples an unflipped rectangle's texture right)."""
    radiance = dict(radiance)
    if not flipped:
        mirror = mi.ScalarTransform4f().translate([0, 1, 0]).scale([1, -1, 1])
        radiance["to_uv"] = radiance.get("to_uv", mi.ScalarTransform4f()) @ mirror
    d = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate(list(center))
         .rotate([1, 0, 0], -90 if flipped else 90).scale(size), "bsdf": diffuse(0.0),
         "emitter": {"type": "area", "radiance": radiance}}
    if flipped:
        d["flip_normals"] = True
    return d


#: (a checkerboard's colours are reflectances: at most 1)
CHECKER_LIGHT = {"type": "checkerboard", "color0": rgb([0.3, 0.25, 0.2]), "color1": rgb([0.9, 0.95, 1.0]),
                 "to_uv": mi.ScalarTransform4f().scale([3, 3, 1])}


def _textured_light_rows():
    """Textured area lights where Mitsuba 3.9.1's own light sampling fails: a bitmap on a
    ``flip_normals`` rectangle, and a checkerboard one mixed with a point light and a
    plain area light. Reference: ``path`` on the same scene with the light unflipped and
    its texture mirrored (:func:`textured_rectangle`)."""
    tex = bitmap(noise((8, 8, 3), 15, 1.0, 10.0))

    def mixed(r, flipped):
        d = stage(r, emitter=textured_rectangle(CHECKER_LIGHT, flipped, size=0.5))
        d["point"] = {"type": "point", "position": [0.5, 1.6, 0.6], "intensity": rgb([0.2, 0.15, 0.1])}
        d["lamp"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([-0.8, 1.8, 0.4])
                     .rotate([1, 0, 0], 90).scale(0.2), "bsdf": diffuse(0.0), "emitter": {
                         "type": "area", "radiance": rgb(1.0)}}
        return d
    why = ("Mitsuba's path gets (almost) no light from a textured flip_normals rectangle through its light "
           "samples (docs/findings.md); the reference is path on the same light unflipped, its texture mirrored")
    return [Row("case:textured_light_flipped", None, lambda r: stage(r, emitter=textured_rectangle(tex, True)),
                reference_scene=lambda r: stage(r, emitter=textured_rectangle(tex, False)),
                note="a bitmap radiance on a flip_normals rectangle light; " + why),
            Row("case:textured_light_mixed", None, lambda r: mixed(r, True), reference_scene=lambda r: mixed(r, False),
                note="a checkerboard flip_normals rectangle light, a point light and a plain area light; " + why)]


# ------------------------------------------------------------------ shapes (the subject)
def _shape_rows():
    mesh = cube_mesh()
    obj = {"type": "obj", "filename": files.obj_file(mesh, "coverage_cube"), "face_normals": True}
    ser = {"type": "serialized", "filename": files.serialized_file(mesh, "coverage_cube"), "face_normals": True}
    ply = shape(mesh, "coverage_cube")
    s = {
        "cube": {"type": "cube", "to_world": subject_transform()},
        "obj": obj, "ply": ply, "serialized": ser,
        "rectangle": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0.4, 0])
                      .rotate([1, 0, 0], -30).scale(0.4)},
        "disk": {"type": "disk", "to_world": mi.ScalarTransform4f().translate([0, 0.4, 0]).rotate([1, 0, 0], -30)
                 .scale(0.4)},
        "sphere": {"type": "sphere", "center": [0.0, 0.35, 0.0], "radius": 0.35},
        "cylinder": {"type": "cylinder", "p0": [0.0, 0.0, 0.0], "p1": [0.0, 0.7, 0.0], "radius": 0.3},
        "instance": {"type": "instance", "shapegroup": {"type": "ref", "id": "group"},
                     "to_world": mi.ScalarTransform4f().translate([0.1, 0, 0])},
        "merge": {"type": "merge", "a": dict(obj), "b": {"type": "cube", "to_world": mi.ScalarTransform4f()
                                                            .translate([0.8, 0.15, 0.3]).scale(0.15)}},
        "ellipsoids": {"type": "ellipsoids", "centers": mi.TensorXf(np.array([[0, 0.35, 0], [0.6, 0.2, 0.3]],
                                                                              np.float32)),
                       "scales": mi.TensorXf(np.array([[0.35, 0.3, 0.3], [0.2, 0.2, 0.2]], np.float32)),
                       "quaternions": mi.TensorXf(np.array([[0, 0, 0, 1], [0, 0, 0, 1]], np.float32))},
        "bsplinecurve": {"type": "bsplinecurve", "filename": files.curve_file(
            [[(-0.5, 0.1, 0, 0.08), (-0.2, 0.6, 0, 0.1), (0.2, 0.1, 0, 0.1), (0.5, 0.6, 0, 0.08)]], "coverage_bspline")},
        "linearcurve": {"type": "linearcurve", "filename": files.curve_file(
            [[(-0.5, 0.1, 0, 0.08), (-0.2, 0.6, 0, 0.1), (0.2, 0.1, 0, 0.1), (0.5, 0.6, 0, 0.08)]], "coverage_linear")},
        "sdfgrid": {"type": "sdfgrid", "grid": mi.TensorXf(_sphere_sdf(8)),
                    "to_world": mi.ScalarTransform4f().translate([-0.35, 0.0, -0.35]).scale(0.7)},
    }
    s["ellipsoidsmesh"] = dict(s["ellipsoids"], type="ellipsoidsmesh")
    rows = []
    for name, d in s.items():
        d = dict(d)
        if name not in ("instance",):
            d["bsdf"] = diffuse(0.5)
        rows.append(Row("shape:" + name, name, (lambda r, d=d: stage(r, subject=d))))
    group = {"type": "shapegroup", "part": dict(ply, bsdf=diffuse(0.5))}
    rows[-len(s) + list(s).index("instance")].build = lambda r: dict(stage(r, subject=s["instance"]), group=group)
    rows.append(Row("shape:shapegroup", "shapegroup", lambda r: dict(stage(r, subject=s["instance"]), group=group),
                    note="a shapegroup is rendered through an instance"))
    rows.append(Row("shape:blender", "blender", na="built by Mitsuba's Blender add-on from Blender's memory; "
                                                   "not constructible from a scene file or dict"))
    return rows


def _sphere_sdf(n):
    g = (np.arange(n) + 0.5) / n
    z, y, x = np.meshgrid(g, g, g, indexing="ij")
    return (np.sqrt((x - 0.5) ** 2 + (y - 0.5) ** 2 + (z - 0.5) ** 2) - 0.4).astype(np.float32)[..., None]


# ------------------------------------------------------------------ sensors
def _sensor_rows():
    at = look_at((0.0, 1.3, 3.4), (0.0, 0.35, 0.0))

    def meter(kind, r, **kw):
        d = {"type": kind, "sampler": {"type": "independent", "sample_count": 4}, "film": film(1, **kw.pop("film", {}))}
        d.update(kw)
        return d
    rows = [
        Row("sensor:perspective", "perspective", lambda r: stage(r)),
        Row("sensor:thinlens", "thinlens", lambda r: stage(r, sensor=camera(r, "thinlens", aperture_radius=0.08,
                                                                            focus_distance=3.0))),
        Row("sensor:orthographic", "orthographic", lambda r: stage(r, sensor=camera(
            r, "orthographic", to_world=at @ mi.ScalarTransform4f().scale([1.2, 1.2, 1.0])))),
        Row("sensor:radiancemeter", "radiancemeter", lambda r: stage(r, sensor=meter(
            "radiancemeter", r, origin=[0.0, 1.3, 3.4], direction=[0.05, -0.3, -1.0])), spp_scale=64),
        Row("sensor:distant", "distant", lambda r: stage(r, sensor=meter(
            "distant", r, direction=[0.0, -1.0, -0.3], target={"type": "rectangle", "to_world": mi.ScalarTransform4f()
                                                                  .rotate([1, 0, 0], -90).scale(0.8)})),
            spp_scale=64),
        # path's value of the meter is noisy (its rays find the small lamp by chance: per-run SD 4 %
        # at 32768 samples): with 8 reference runs the cells detected 12.8-13.9 %, with 64 3.0-4.9 %
        Row("sensor:irradiancemeter", "irradiancemeter", _irradiance_meter, spp_scale=64, reference_runs=64),
        Row("sensor:batch", "batch", lambda r: stage(r, sensor={
            "type": "batch", "sampler": {"type": "independent", "sample_count": 4},
            "film": {"type": "hdrfilm", "width": 2 * r, "height": r, "rfilter": {"type": "box"}},
            "left": {"type": "perspective", "fov": 40.0, "to_world": at},
            "right": {"type": "perspective", "fov": 40.0, "to_world": look_at((1.5, 1.0, 3.0), (0.0, 0.35, 0.0))}})),
    ]
    return rows


def _irradiance_meter(r):
    d = stage(r)
    d["meter"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0.8, 0.001, 0.6])
                  .rotate([1, 0, 0], -90).scale(0.2), "bsdf": diffuse(0.5),
                  "sensor": {"type": "irradiancemeter", "sampler": {"type": "independent", "sample_count": 4},
                             "film": film(1)}}
    del d["sensor"]
    return d


# ------------------------------------------------------------------ films, pixel formats, filters
def _film_rows():
    rows = [Row("film:hdrfilm", "hdrfilm", lambda r: stage(r)),
            Row("film:specfilm", "specfilm", na="Mitsuba refuses specfilm outside spectral variants; the package "
                                                "renders RGB variants")]
    for fmt in ("rgba", "luminance", "luminance_alpha", "xyz", "xyza"):
        rows.append(Row("format:" + fmt, None, (lambda r, fmt=fmt: _with_film(r, pixel_format=fmt))))
    rows.append(Row("case:crop_window", None, lambda r: _with_film(
        r, crop_offset_x=r // 4, crop_offset_y=r // 8, crop_width=r // 2, crop_height=r // 2)))
    rows.append(Row("case:envmap_alpha", None, lambda r: dict(stage(r, emitter={
        "type": "envmap", "bitmap": sky_bitmap()}), sensor=camera(r, film=film(r, pixel_format="rgba"),
                                                                  to_world=look_at((0, 1.0, 3.4), (0, 0.9, 0)))),
        note="an rgba film where the camera sees the sky: alpha is the share of each pixel covered by surfaces"))
    for name in ("box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos"):
        rows.append(Row("rfilter:" + name, name, (lambda r, name=name: _with_film(r, rfilter={"type": name}))))
    return rows


def _with_film(r, **kw):
    d = stage(r)
    d["sensor"]["film"].update(kw)
    return d


# ------------------------------------------------------------------ textures (floor reflectance, light radiance)
def _texture_rows():
    mesh = quad((0, 0, 0), (1.5, 0, 0), (0, 0, -1.5), 4)
    colors = np.stack([0.2 + 0.6 * (mesh.vertices[:, 0] + 1.5) / 3, 0.5 + 0 * mesh.vertices[:, 0],
                       0.2 + 0.6 * (mesh.vertices[:, 2] + 1.5) / 3], axis=1)
    colored_floor = {"type": "ply", "filename": files.colored_ply_file(mesh, colors, "coverage_floor_rgb"),
                     "face_normals": True,
                     "bsdf": {"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}}}
    t = {
        "bitmap": bitmap(noise((8, 8, 3), 5, 0.1, 0.9)),
        "checkerboard": {"type": "checkerboard", "color0": rgb(0.15), "color1": rgb(0.8),
                         "to_uv": mi.ScalarTransform4f().scale([4, 4, 1])},
        "volume": {"type": "volume", "volume": {"type": "gridvolume", "data": mi.TensorXf(
            noise((4, 4, 4, 3), 6, 0.1, 0.9).astype(np.float32)), "to_world": mi.ScalarTransform4f()
            .translate([-1.5, -0.5, -1.5]).scale(3.0)}},
        "uniform": {"type": "uniform", "value": 0.45},
        "srgb": {"type": "srgb", "color": [0.6, 0.4, 0.2]},
        "rawconstant": {"type": "rawconstant", "value": 0.45},
    }
    rows = [Row("texture:" + name, name, (lambda r, d=d: stage(r, floor_bsdf={"type": "diffuse", "reflectance": d})))
            for name, d in t.items()]
    rows.append(Row("texture:mesh_attribute", "mesh_attribute", lambda r: dict(stage(r), floor=colored_floor)))
    # d65 is white in the RGB variants (its value is its scale): 6, the stage light's radiance (at 1/30 the
    # image mean, 2.5e-4, was so dark that the float tolerance alone made 8 % of a cell's power)
    spectra = {"d65": {"type": "d65", "scale": 6.0}, "blackbody": {"type": "blackbody", "temperature": 4000},
               "irregular": {"type": "irregular", "wavelengths": "400, 550, 700", "values": "2, 5, 3"},
               "regular": {"type": "regular", "wavelength_min": 400, "wavelength_max": 700, "values": "2, 5, 3"}}
    broken = ("Mitsuba 3.9.1 refuses it in RGB variants during the render (eval(): not implemented!, with path "
              "too): there is no reference (docs/findings/rgb_variant_spectra_fail_at_render.py)")
    for name in ("irregular", "regular"):
        spectra.pop(name)
        rows.append(Row("texture:" + name, name, na=broken))
    rows.append(Row("texture:blackbody", "blackbody", na="Mitsuba refuses it outside spectral variants (during the "
                                                         "render, with path too; docs/findings/rgb_variant_spectra_"
                                                         "fail_at_render.py); the package renders RGB variants"))
    spectra.pop("blackbody")
    for name, d in spectra.items():
        rows.append(Row("texture:" + name, name, (lambda r, d=d: stage(r, emitter=dict(
            light(), emitter={"type": "area", "radiance": d}))), note="as the light's radiance"))
    return rows


# ------------------------------------------------------------------ media, phase functions, volumes
def _medium_box(medium):
    return {"type": "cube", "to_world": subject_transform(), "bsdf": {"type": "null"}, "interior": medium}


def _medium_rows():
    grid = lambda ch, seed, lo, hi: {"type": "gridvolume", "data": mi.TensorXf(
        noise((4, 4, 4, ch), seed, lo, hi).astype(np.float32)), "to_world": mi.ScalarTransform4f()
        .translate([-0.35, 0.0, -0.35]).scale(0.7)}
    homog = lambda phase=None: dict({"type": "homogeneous", "sigma_t": 2.0, "albedo": rgb(0.8)},
                                    **({"phase": phase} if phase else {}))
    sggx = {"type": "sggx", "S": {"type": "gridvolume", "data": mi.TensorXf(
        np.tile(np.array([1, 0.5, 0.8, 0, 0, 0], np.float32), (2, 2, 2, 1)))}}
    phases = {"isotropic": {"type": "isotropic"}, "hg": {"type": "hg", "g": 0.6}, "rayleigh": {"type": "rayleigh"},
              "sggx": sggx, "tabphase": {"type": "tabphase", "values": "0.5, 1.0, 2.0"},
              "blendphase": {"type": "blendphase", "weight": 0.4, "phase1": {"type": "isotropic"},
                             "phase2": {"type": "hg", "g": 0.6}}}
    rows = [Row("medium:homogeneous", "homogeneous", lambda r: stage(r, subject=_medium_box(homog())),
                reference="volpath"),
            Row("medium:heterogeneous", "heterogeneous", lambda r: stage(r, subject=_medium_box({
                "type": "heterogeneous", "sigma_t": grid(1, 7, 0.5, 3.0), "albedo": rgb(0.8)})), reference="volpath")]
    rows += [Row("phase:" + name, name, (lambda r, p=p: stage(r, subject=_medium_box(homog(p)))), reference="volpath")
             for name, p in phases.items()]
    rows.append(Row("volume:gridvolume", "gridvolume", lambda r: stage(r, subject=_medium_box({
        "type": "heterogeneous", "sigma_t": grid(1, 8, 0.5, 3.0), "albedo": grid(3, 9, 0.3, 0.9)})),
        reference="volpath"))
    rows.append(Row("volume:constvolume", "constvolume", lambda r: stage(r, subject=_medium_box({
        "type": "heterogeneous", "sigma_t": {"type": "constvolume", "value": 1.5},
        "albedo": {"type": "constvolume", "value": rgb(0.7)}})), reference="volpath"))
    rows.append(Row("case:camera_in_medium", None, lambda r: dict(stage(r), sensor=dict(
        camera(r), medium={"type": "homogeneous", "sigma_t": 0.05, "albedo": rgb(0.5)})), reference="volpath",
        note="a homogeneous medium around the camera (the sensor's medium)"))
    return rows


# ------------------------------------------------------------------ samplers
def _sampler_rows(package_samplers):
    def with_sampler(r, name):
        d = stage(r)
        d["sensor"]["sampler"] = {"type": name, "sample_count": 4}
        return d
    names = ["independent", "stratified", "multijitter", "orthogonal", "ldsampler"] + list(package_samplers)
    return [Row(("sampler:" if i < 5 else "package:") + name, name, (lambda r, n=name: with_sampler(r, n)),
                reference_scene=lambda r: stage(r), note="reference: path with the independent sampler")
            for i, name in enumerate(names)]


# ------------------------------------------------------------------ integrators
WRAPPERS = {"aov": lambda inner: {"type": "aov", "aovs": "dd.y:depth", "integrator": inner},
            "moment": lambda inner: {"type": "moment", "integrator": inner}}
NOT_A_FEATURE = ("an integrator of its own, not a feature of a scene; path, volpath and ptracer are this matrix's "
                 "references")


def _integrator_rows():
    rows = [Row("integrator:" + name, name, lambda r: stage(r), wrap=w) for name, w in WRAPPERS.items()]
    rows += [Row("integrator:" + name, name, na=NOT_A_FEATURE)
             for name in ("path", "volpath", "volpathmis", "ptracer", "direct", "depth", "stokes")]
    return rows


# ------------------------------------------------------------------ cases that are no plugin
def _case_rows():
    def cove(r):
        d = stage(r, emitter=shape(quad((0.0, 1.9, 0.0), (0.4, 0, 0), (0, 0, -0.4)), "coverage_cove_light",
                                   diffuse(0.0), area(8.0)))      # facing up
        d["ceiling"] = shape(quad((0.0, 1.91, 0.0), (0.6, 0, 0), (0, 0, 0.6), 2), "coverage_cove_ceiling",
                             diffuse(0.8))                         # facing down, 1 cm above the light
        return d

    def negative(r):
        d = stage(r)
        d["dark"] = shape(quad((-0.6, 1.5, 0.5), (0.2, 0, 0), (0, 0, 0.2)), "coverage_negative_light",
                          diffuse(0.0), area(-2.0))
        return d

    def flipped(r):
        d = stage(r)
        d["floor"] = shape(quad((0, 0, 0), (1.5, 0, 0), (0, 0, -1.5), 4).flipped(), "stage_floor_flipped",
                           diffuse(0.5), flip_normals=True)
        return d
    def no_emitters(r):
        d = stage(r)
        del d["light"]
        return d
    def hidden_light(r):
        d = stage(r, emitter={"type": "envmap", "bitmap": sky_bitmap()})
        d["lamp"] = light()
        d["sensor"]["to_world"] = look_at((0.0, 3.5, 0.6), (0.0, 0.0, 0.1), (0, 0, -1))
        return d
    rows = [Row("case:hide_emitters", None, hidden_light, params={"hide_emitters": True},
                note="hide_emitters: the camera above the lamp sees through it (Mitsuba's meaning), and not the sky"),
            Row("case:no_shapes", None, lambda r: {"type": "scene", "sensor": camera(r), "sky": {
                "type": "envmap", "bitmap": sky_bitmap()}}, note="a scene of a sensor and an environment map only"),
            Row("case:no_emitters", None, no_emitters, note="the stage without its light: a black image"),
            Row("case:light_facing_ceiling", None, cove, note="an area light facing a ceiling 1 cm above it",
                reference_runs=32),
            Row("case:negative_emission", None, negative, note="an area light of radiance -2 beside the stage light"),
            Row("case:flip_normals", None, flipped, note="the floor wound downward, with flip_normals"),
            Row("case:sphere_uneven_scale", None, lambda r: stage(r, subject={
                "type": "sphere", "to_world": mi.ScalarTransform4f().translate([0, 0.3, 0]).scale([0.45, 0.3, 0.3]),
                "bsdf": diffuse(0.5)}), note="a sphere whose to_world scales its axes unevenly (Mitsuba warns and "
                                             "renders a sphere of the first axis' radius)"),
            Row("case:cylinder_elliptic", None, lambda r: stage(r, subject={
                "type": "cylinder", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale([0.2, 0.35, 0.6]),
                "bsdf": diffuse(0.5)}), note="an open cylinder of elliptic cross-section (Mitsuba warns; its surface "
                                             "area is a circle's)"),
            Row("case:open_many_emitters", None, open_many_emitters, max_depth=4,
                note="large one-sided rectangle planes of albedo 1, seven emitters, max_depth 4 (after Mitsuba's "
                     "own emitter render tests)")]
    for depth in (1, 2, 3):
        rows.append(Row("depth:%d" % depth, None, lambda r: stage(r), max_depth=depth))
        rows.append(Row("depth:%d_point" % depth, None, (lambda r: stage(r, emitter=_emitter_rows()[1].build(r)
                                                                         ["light"])), max_depth=depth))
    return rows


def open_many_emitters(r):
    """Two large white planes (albedo 1: a floor and a back wall, ``rectangle``s), area
    lights on a rectangle, a bitmap-textured obj quad and an obj sphere (its radiance
    uniform: Mitsuba's ``path`` is biased on a textured one, docs/findings.md), a
    ``spot``, a bitmap-textured ``spot`` and a ``projector``, seen from far away."""
    tex = lambda seed: bitmap(noise((8, 8, 3), seed, 0.3, 1.0))
    sphere = files.obj_file(_icosphere(), "coverage_sphere")
    quad_obj = files.obj_file(quad((0, 0, 0), (1, 0, 0), (0, 0, -1)), "coverage_quad")
    white = diffuse(1.0)
    d = {"type": "scene",
         "sensor": dict(camera(r, to_world=look_at((0, 8, 30), (0, 2, 0)), fov=30.0),
                        film=dict(film(r), width=4 * r, height=r // 2 if r >= 8 else r)),
         "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(40), "bsdf": white},
         "wall": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -10]).scale(40), "bsdf": white},
         "rect_light": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([-12, 6, 0])
                        .rotate([1, 0, 0], 90).scale(1.5), "emitter": area(6.0)},
         "quad_light": {"type": "obj", "filename": quad_obj, "to_world": mi.ScalarTransform4f().translate([-4, 6, 0])
                        .rotate([1, 0, 0], 180).scale(1.5), "emitter": {"type": "area", "radiance": tex(11)}},
         "sphere_light": {"type": "obj", "filename": sphere, "to_world": mi.ScalarTransform4f().translate([4, 3, 0]),
                          "emitter": area(0.6)},
         "spot": {"type": "spot", "to_world": look_at((10, 8, 2), (10, 0, 0), (0, 0, 1)), "cutoff_angle": 25.0,
                  "intensity": rgb(60.0)},
         "spot_tex": {"type": "spot", "to_world": look_at((16, 8, 2), (16, 0, 0), (0, 0, 1)), "cutoff_angle": 25.0,
                      "intensity": rgb(60.0), "texture": tex(13)},
         "projector": {"type": "projector", "to_world": look_at((22, 8, 2), (22, 0, 0), (0, 0, 1)), "fov": 40.0,
                       "scale": 40.0, "irradiance": tex(14)}}
    return d


def _icosphere():
    from mi_plugins.verify import geometry
    return geometry.icosphere(2, 1.0, inward=False)


def package_rows():
    """Rows of the package's own plugins (BSDFs, emitters, samplers)."""
    from mi_plugins.samplers import PLUGINS as SAMPLERS
    rows = [Row("package:phong", "phong", lambda r: stage(r, subject_bsdf={
                "type": "phong", "diffuse_reflectance": rgb(0.4), "specular_reflectance": rgb(0.3), "exponent": 10.0})),
            Row("package:separable", "separable", lambda r: stage(r, subject_bsdf={
                "type": "separable", "target_radiance": 1.0}), note="no emission: f = 1/pi (albedo 1)"),
            Row("package:simulated_area", "simulated_area", _simulated_wall,
                note="simulated emission (uniform estimator) on the stage's back wall"),
            Row("package:directional_area", "directional_area", lambda r: stage(r, emitter=dict(light(), emitter={
                "type": "directional_area", "radiance": rgb(6.0), "exponent": 2.0})))]
    rows += _sampler_rows(SAMPLERS)[5:]
    return rows


def _simulated_wall(r):
    d = stage(r)
    d["wall"]["emitter"] = {"type": "simulated_area", "target_radiance": 0.4, "estimator": "uniform"}
    return d


#: rows whose images are noisy at the base budget (caustics, a light seen only through a
#: 1 cm gap, emitters of both signs, a large open scene): their cells and references take
#: this many times the samples, so that every cell sees a 10 % error
NOISY = {"bsdf:dielectric": 4, "bsdf:roughdielectric": 8, "bsdf:null": 2, "bsdf:retarder": 2, "case:crop_window": 2,
         "case:light_facing_ceiling": 32, "case:negative_emission": 8,
         "case:open_many_emitters": 16}


def all_rows():
    """Every row, in table order: {key: Row}."""
    rows = (_bsdf_rows() + _emitter_rows() + _shape_rows() + _sensor_rows() + _film_rows() + _texture_rows()
            + _medium_rows() + _sampler_rows(())[:5] + _integrator_rows() + _case_rows() + package_rows()
            + mesh_rows(Row) + gap_rows(Row))
    table = {}
    for row in rows:
        if row.key in table:
            raise ValueError("two coverage rows named %r" % row.key)
        row.spp_scale *= NOISY.get(row.key, 1)
        table[row.key] = row
    return table
