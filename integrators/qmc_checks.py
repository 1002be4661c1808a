"""What ``qmc_lighttrace`` refuses before any work, and the limits of its work.

- shapes without patches: the patches are the triangles of meshes and cells of
  ``rectangle``, ``disk``, ``sphere`` and ``cylinder`` (``mi_plugins.meshtable``);
- emitters whose light leaves a surface in one direction only (``directionalarea``):
  the direct light of a point is a light sample there, which such an emitter never
  gives (Mitsuba's ``path`` renders it black), while the particles would carry its
  indirect light: neither ``path``'s image nor the physical one.

The limits: paths and gather samples by the parameter reader, eye rays x gather samples
by :func:`check_gather_lanes`, deposit layers x patches by ``qmc_store.check_memory``,
each against a documented maximum and the available memory.
"""
import mitsuba as mi

from mi_plugins import support, tessellation
from mi_plugins.meshtable import _is_mesh
from mi_plugins.params import parameter_error

PATCHABLE = ", ".join(sorted(k.lower() for k in tessellation.KINDS))


def refuse_shapes_without_patches(plugin, scene):
    for shape in scene.shapes():
        if tessellation.shape_kind(shape) not in tessellation.KINDS and not _is_mesh(shape):
            name = support.plugin_name(shape)
            raise support.Unsupported(
                plugin, name, "the shape '%s' (plugin '%s')" % (shape.id(), name),
                "%s stores light per patch, and only triangle meshes and Mitsuba's %s are divided into patches"
                % (plugin, PATCHABLE),
                "convert the shape to a triangle mesh (a 'ply' or 'obj' file), or render with Mitsuba's 'path'")


def refuse_one_direction_emitters(plugin, scene):
    for emitter in scene.emitters():
        flags = emitter.flags()
        if mi.has_flag(flags, mi.EmitterFlags.DeltaDirection) and mi.has_flag(flags, mi.EmitterFlags.Surface):
            name = support.plugin_name(emitter)
            shape = emitter.get_shape()
            raise support.Unsupported(
                plugin, name, "the emitter '%s'%s" % (name, " of shape '%s'" % shape.id() if shape else ""),
                "it emits in one direction only: the direct light of the points seen comes from light samples, "
                "which never reach it (Mitsuba's 'path' renders it black), while the particles would carry its "
                "indirect light", "render it with Mitsuba's 'ptracer', or use an 'area' emitter")



#: bytes per gather lane of a render (its numbers, state and result)
BYTES_PER_GATHER_LANE = 64


def check_gather_lanes(plugin, frame, gather_samples):
    """Refuse before any work (a Params-style error naming gather_samples) when the eye
    rays x gather samples of one render exceed 2^32 lanes or half the available memory."""
    from mi_plugins.integrators.qmc_store import available_memory
    film = frame.film
    border = film.rfilter().border_size() if film.sample_border() else 0
    lanes = (frame.width + 2 * border) * (frame.height + 2 * border) * frame.spp * int(gather_samples)
    available = available_memory()
    if lanes >= 1 << 32 or (available is not None and lanes * BYTES_PER_GATHER_LANE > available // 2):
        raise parameter_error(plugin, [("gather_samples", gather_samples)], (
            "a count whose %d eye rays x gather samples (%d lanes here) stay below 2^32 lanes and half the "
            "available memory (%d bytes per lane); use fewer gather_samples or samples per pixel, or render in "
            "passes" % (lanes // int(gather_samples), lanes, BYTES_PER_GATHER_LANE)))
