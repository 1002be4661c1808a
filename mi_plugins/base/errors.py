"""What the package's integrators handle, checked before any work.

Every integrator of the package calls its checks at the start of ``render()``: a scene
feature it cannot render right raises :class:`Unsupported`, whose message names the
integrator, the feature (the Mitsuba plugin and the object's id), why, and what to
use instead. The coverage matrix (``mi-plugins verify --suite coverage``) holds every
feature Mitsuba can put in a scene against these checks.
"""
import re

import mitsuba as mi

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


class Unsupported(ValueError):
    """A scene feature an integrator does not render right: raised before any work.
    ``integrator``: the plugin refusing; ``feature``: the Mitsuba plugin (or case) name."""

    def __init__(self, integrator, feature, subject, why, instead):
        self.integrator, self.feature = integrator, feature
        super().__init__("%s: %s is not supported: %s; %s" % (integrator, subject, why, instead))


class NotConverged(RuntimeError):
    """An iterative integrator whose average would stay measurably biased within its
    stated limit of iterations: raised instead of returning that image. ``needed``: the
    iterations the measurement predicts (0 where it cannot say)."""

    def __init__(self, integrator, what, needed, limit, instead):
        self.integrator, self.needed, self.limit = integrator, int(needed), int(limit)
        need = "it needs about %d iterations" % needed if needed else "it needs more iterations"
        super().__init__("%s: not converged within max_iterations=%d: %s; %s: raise max_iterations to at least %d, "
                         "or %s" % (integrator, limit, what, need, max(needed, 2 * limit), instead))


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


def refuse_media(integrator, scene, sensor, instead="render participating media with Mitsuba's 'volpath'"):
    """Raise :class:`Unsupported` when ``scene`` holds a participating medium (inside or
    outside a shape, or around the sensor)."""
    found = []
    if sensor is not None and sensor.get_medium() is not None:
        found.append((sensor.get_medium(), "around the sensor"))
    for shape in scene.shapes():
        for medium, side in ((shape.interior_medium(), "interior"), (shape.exterior_medium(), "exterior")):
            if medium is not None:
                found.append((medium, "the %s of shape '%s'" % (side, shape.id())))
    if found:
        medium, where = found[0]
        raise Unsupported(integrator, plugin_name(medium), describe(medium, "participating medium") + ", " + where,
                          "light is transported between surfaces only (no scattering or absorption in volumes)",
                          instead)


def refuse_sensor(integrator, sensor, supported, why, instead="render with Mitsuba's 'path'"):
    """Raise :class:`Unsupported` unless the sensor's plugin is one of ``supported``."""
    name = plugin_name(sensor)
    if name not in supported:
        raise Unsupported(integrator, name, describe(sensor, "sensor"), why, instead)


def refuse_classes(integrator, scene, classes, why, instead):
    """Raise :class:`Unsupported` when a shape's BSDF is (or nests) one of ``classes``
    (Mitsuba class names)."""
    for shape, bsdf in bsdfs(scene):
        found = nested_classes(bsdf) & set(classes)
        if found:
            name = PLUGIN_OF_CLASS.get(sorted(found)[0], sorted(found)[0])
            raise Unsupported(integrator, name, "the BSDF '%s' of shape '%s'" % (name, shape.id()), why, instead)


def refuse_shapes_without_patches(integrator, scene):
    """Raise :class:`Unsupported` for a shape that is neither a triangle mesh nor one of
    the analytic shapes divided into patches (``rectangle``, ``disk``, ``sphere``,
    ``cylinder``: :mod:`mi_plugins.patches.tessellation`), or one whose ``to_world`` Mitsuba
    itself does not follow (:func:`~mi_plugins.patches.tessellation.distortion`), for the
    finite-element integrators."""
    from mi_plugins.patches import tessellation
    from mi_plugins.base.queries import is_mesh
    for shape in scene.shapes():
        if is_mesh(shape):
            continue
        if tessellation.shape_kind(shape) not in tessellation.KINDS:
            name = plugin_name(shape)
            raise Unsupported(
                integrator, name, "the shape '%s' (id '%s')" % (name, shape.id()),
                "%s stores light per patch, and only triangle meshes and Mitsuba's %s are divided into patches"
                % (integrator, ", ".join(sorted(k.lower() for k in tessellation.KINDS))),
                "convert the shape to a triangle mesh (a 'ply' or 'obj' file), or render with Mitsuba's 'path'")
        reason = tessellation.distortion(shape)
        if reason:
            name = tessellation.shape_kind(shape).lower()
            raise Unsupported(
                integrator, name, "the shape '%s' (id '%s')" % (name, shape.id()), reason,
                "give it a uniform scale (a sphere: its 'center' and 'radius'; a cylinder: the same scale along "
                "its first two axes, any along its length), or make it a triangle mesh")


def refuse_one_direction_emitters(integrator, scene):
    """Raise :class:`Unsupported` for a surface emitter whose light leaves in one
    direction only (``directionalarea``): the direct light of a point comes from light
    samples, which never reach it (Mitsuba's ``path`` renders it black), while light
    transported between surfaces would carry it."""
    for emitter in scene.emitters():
        flags = emitter.flags()
        if mi.has_flag(flags, mi.EmitterFlags.DeltaDirection) and mi.has_flag(flags, mi.EmitterFlags.Surface):
            name = plugin_name(emitter)
            shape = emitter.get_shape()
            raise Unsupported(
                integrator, name, "the emitter '%s'%s" % (name, " of shape '%s'" % shape.id() if shape else ""),
                "it emits in one direction only: the direct light of the points seen comes from light samples, "
                "which never reach it (Mitsuba's 'path' renders it black), while light carried between surfaces "
                "would bring its indirect light", "render it with Mitsuba's 'ptracer', or use an 'area' emitter")


def sensors_of(scene, sensor):
    """``sensor`` (an index or a Sensor) as a Sensor of ``scene``."""
    if isinstance(sensor, int):
        return scene.sensors()[sensor]
    return sensor


def refuse_textured_lights_behind_handoff(integrator, scene, why_handoff):
    """Raise :class:`Unsupported` for a textured area light that Mitsuba 3.9.1 samples
    wrongly (:func:`mi_plugins.light.sources.mitsuba_samples_right`: a ``flip_normals``
    rectangle, a mesh whose uv map does not tile the unit square) in a scene whose light
    the integrator hands to Mitsuba's ``volpath`` (``why_handoff``: which surfaces):
    ``volpath``'s light samples of it are wrong (docs/findings.md)."""
    from mi_plugins.light.sources import mitsuba_samples_right, textured_area_lights
    for _, emitter, _ in textured_area_lights(scene):
        if not mitsuba_samples_right(emitter):
            shape = emitter.get_shape()
            raise Unsupported(
                integrator, "area", "the textured 'area' emitter of shape '%s' (%s)" % (
                    shape.id(), "a flip_normals rectangle" if shape.class_name() == "Rectangle" else
                    "its uv map does not cover the unit square once"),
                "the light reaching %s is estimated by Mitsuba's 'volpath', whose light samples of such a light "
                "are wrong (Mitsuba samples a textured radiance through the shape's uv map)" % why_handoff,
                "render it with 'qmc_lighttrace', or give the light an untextured radiance, an unflipped "
                "rectangle or a mesh whose uv map covers the unit square once")
