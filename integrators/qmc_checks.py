"""What ``qmc_lighttrace`` refuses before any work, and the limits of its work.

- shapes without patches: the patches are the triangles of meshes and cells of
  ``rectangle``, ``disk``, ``sphere`` and ``cylinder`` (``mi_plugins.meshtable``);
- emitters whose light leaves a surface in one direction only (``directionalarea``):
  the direct light of a point is a light sample there, which such an emitter never
  gives (Mitsuba's ``path`` renders it black), while the particles would carry its
  indirect light: neither ``path``'s image nor the physical one.

The limits (paths, gather samples, deposit layers x patches against the memory) are
checked by the parameter reader and ``qmc_store.check_memory``.
"""
import mitsuba as mi

from mi_plugins import support, tessellation
from mi_plugins.meshtable import _is_mesh

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

