"""What Mitsuba can put in a scene, read from the installed Mitsuba itself.

The wheel's ``plugins`` folder holds one shared library per plugin; Mitsuba's plugin
manager tells each one's kind. :func:`mitsuba_plugins` lists them all, so that a
Mitsuba release that adds a plugin adds a line here without anyone writing it.
"""
import os

import mitsuba as mi

#: Mitsuba's object types -> the kind names of the coverage rows
KINDS = {"BSDF": "bsdf", "Emitter": "emitter", "Shape": "shape", "Sensor": "sensor", "Film": "film",
         "ReconstructionFilter": "rfilter", "Texture": "texture", "Medium": "medium", "PhaseFunction": "phase",
         "Volume": "volume", "Sampler": "sampler", "Integrator": "integrator"}


def plugin_folder():
    return os.path.join(os.path.dirname(mi.__file__), "plugins")


def mitsuba_plugins():
    """{plugin name: kind} of every plugin in the installed Mitsuba wheel (kinds as in
    :data:`KINDS`; 'other' for a kind the table does not know)."""
    manager = mi.PluginManager.instance()
    plugins = {}
    for entry in sorted(os.listdir(plugin_folder())):
        name, ext = os.path.splitext(entry)
        if ext not in (".so", ".dll", ".dylib") or name.startswith("lib"):
            continue
        kind = str(manager.plugin_type(name)).rsplit(".", 1)[-1]
        plugins[name] = KINDS.get(kind, "other")
    return plugins
