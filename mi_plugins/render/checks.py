"""What the package's integrators refuse, checked before any work: each check raises
:class:`~mi_plugins.base.errors.Unsupported`, naming the integrator, the feature (the
Mitsuba plugin and the object's id), why, and what to use instead. The coverage matrix
(``mi-plugins verify --suite coverage``) holds every feature Mitsuba can put in a scene
against these checks."""
import mitsuba as mi

from mi_plugins.base.errors import Unsupported
from mi_plugins.base.queries import describe, is_mesh, plugin_name
from mi_plugins.light.sources import mitsuba_samples_right, textured_area_lights
from mi_plugins.patches import tessellation


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


def refuse_shapes_without_patches(integrator, scene):
    """Raise :class:`Unsupported` for a shape that is neither a triangle mesh nor one of
    the analytic shapes divided into patches (``rectangle``, ``disk``, ``sphere``,
    ``cylinder``: :mod:`mi_plugins.patches.tessellation`), or one whose ``to_world`` Mitsuba
    itself does not follow (:func:`~mi_plugins.patches.tessellation.distortion`), for the
    finite-element integrators."""
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


def refuse_textured_lights_behind_handoff(integrator, scene, why_handoff):
    """Raise :class:`Unsupported` for a textured area light that Mitsuba 3.9.1 samples
    wrongly (:func:`mi_plugins.light.sources.mitsuba_samples_right`: a ``flip_normals``
    rectangle, a mesh whose uv map does not tile the unit square) in a scene whose light
    the integrator hands to Mitsuba's ``volpath`` (``why_handoff``: which surfaces):
    ``volpath``'s light samples of it are wrong (docs/findings.md)."""
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
