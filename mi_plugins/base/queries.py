"""What a scene holds, asked of Mitsuba's objects: plugin names and descriptions for
messages, the shapes' BSDFs and sides, the scene's bounds."""
import re

import mitsuba as mi
import numpy as np

#: Mitsuba class names (as ``class_name()`` and printing report them) -> plugin names
PLUGIN_OF_CLASS = {
    # media, sensors
    "HomogeneousMedium": "homogeneous", "HeterogeneousMedium": "heterogeneous",
    "PerspectiveCamera": "perspective", "ThinLensCamera": "thinlens", "OrthographicCamera": "orthographic",
    "RadianceMeter": "radiancemeter", "IrradianceMeter": "irradiancemeter", "BatchSensor": "batch",
    "DistantSensorImpl": "distant", "DistantSensor": "distant",
    # BSDFs
    "SmoothDiffuse": "diffuse", "Null": "null", "MaskBSDF": "mask", "TwoSidedBRDF": "twosided", "Hair": "hair",
    "BumpMap": "bumpmap", "NormalMap": "normalmap", "BlendBSDF": "blendbsdf", "SmoothConductor": "conductor",
    "RoughConductor": "roughconductor", "SmoothDielectric": "dielectric", "RoughDielectric": "roughdielectric",
    "ThinDielectric": "thindielectric", "SmoothPlastic": "plastic", "RoughPlastic": "roughplastic",
    "PolarizedPlastic": "pplastic", "Principled": "principled", "PrincipledThin": "principledthin",
    "LinearPolarizer": "polarizer", "LinearRetarder": "retarder", "CircularPolarizer": "circular",
    # emitters
    "SpotLight": "spot", "Projector": "projector", "PointLight": "point", "DirectionalEmitter": "directional",
    "AreaLight": "area", "DirectionalArea": "directionalarea", "EnvironmentMapEmitter": "envmap",
    "ConstantBackgroundEmitter": "constant", "SunskyEmitter": "sunsky", "TimedSunskyEmitter": "timed_sunsky",
    # shapes
    "Instance": "instance", "Ellipsoids": "ellipsoids", "EllipsoidsMesh": "ellipsoidsmesh",
    "BSplineCurve": "bsplinecurve", "LinearCurve": "linearcurve", "SDFGrid": "sdfgrid",
}


#: the sensor plugins of Mitsuba (by the names above)
SENSOR_PLUGINS = ("perspective", "thinlens", "orthographic", "radiancemeter", "irradiancemeter", "batch", "distant")


def plugin_name(obj):
    """The Mitsuba plugin name of ``obj`` (its class name where the table does not know it)."""
    name = obj.class_name() if hasattr(obj, "class_name") else type(obj).__name__
    return PLUGIN_OF_CLASS.get(name, name)


def describe(obj, kind):
    """"the <kind> '<plugin>' (id '<id>')" for messages."""
    ident = obj.id() if hasattr(obj, "id") else ""
    named = " (id '%s')" % ident if ident and not ident.startswith("_unnamed") else ""
    return "the %s '%s'%s" % (kind, plugin_name(obj), named)


def nested_classes(obj):
    """Class names of ``obj`` and of every object nested in it (read from Mitsuba's
    printout, which lists nested plugins by class: e.g. a ``twosided`` BSDF around a
    ``bumpmap``)."""
    return set(re.findall(r"([A-Z][A-Za-z0-9_]*)\[", str(obj)))


def bsdfs(scene):
    """(shape, bsdf) of every shape of ``scene`` that has a BSDF."""
    return [(s, s.bsdf()) for s in scene.shapes() if s.bsdf() is not None]


def reflects_on_both_sides(shape):
    """Whether the BSDF of ``shape`` reflects light on the back of its surface too
    (``twosided``)."""
    bsdf = shape.bsdf()
    flags = int(bsdf.flags()) if bsdf is not None else 0
    return bool(flags & int(mi.BSDFFlags.BackSide)) and bool(flags & int(mi.BSDFFlags.Smooth))


def is_mesh(shape):
    """Whether ``shape`` is a triangle mesh with vertex positions (``rectangle`` reports
    itself a mesh and has none)."""
    return isinstance(shape, mi.Mesh) and "vertex_positions" in mi.traverse(shape).keys()


def scene_bounds(scene):
    """(min, max) corners (numpy float64) of the box around every shape of ``scene``.

    Not ``scene.bbox()``: ``mi.load_dict`` (optimize=True) merges shapes that share a BSDF
    into one ``Mesh`` whose ``bbox()`` is invalid, and ``scene.bbox()`` leaves it out
    (Mitsuba 3.9.1: two 80 x 80 ``rectangle`` planes with one BSDF vanish from it), so a
    size derived from it can be 5x too small. A mesh with an invalid box is bounded by
    its vertices."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for shape in scene.shapes():
        box = shape.bbox()
        if box.valid():
            points = np.array([box.min, box.max], dtype=np.float64)
        elif is_mesh(shape):
            points = np.array(mi.traverse(shape)["vertex_positions"], dtype=np.float64).reshape(-1, 3)
        else:
            continue
        if len(points):
            lo, hi = np.minimum(lo, points.min(axis=0)), np.maximum(hi, points.max(axis=0))
    if not np.all(np.isfinite(lo)):
        box = scene.bbox()
        lo, hi = ((np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)) if box.valid()
                  else (np.zeros(3), np.zeros(3)))
    return lo, hi
