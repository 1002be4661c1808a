"""Registration of the package's plugins with Mitsuba's plugin manager.

Each plugin folder (``integrators``, ``bsdfs``, ``emitters``, ``samplers``)
lists its plugins in a ``PLUGINS`` dict ``{mitsuba_name: "module:Class"}``: the one
place a plugin's name is written; registration gives the class its ``plugin``
attribute (messages, parameter errors).
Plugin classes derive from variant-specific Mitsuba base classes, so their
modules are (re)loaded for the variant being registered.
"""
import importlib

import mitsuba as mi

#: plugin folder (subpackage of mi_plugins) -> Mitsuba plugin kind
KINDS = {
    "integrators": "integrator",
    "bsdfs": "bsdf",
    "emitters": "emitter",
    "samplers": "sampler",
}

_loaded_for = {}  # module name -> variant its classes were built for


def _plugin_class(module_name, class_name, variant):
    module = importlib.import_module(module_name)
    if _loaded_for.get(module_name) not in (None, variant):
        module = importlib.reload(module)
    _loaded_for[module_name] = variant
    return getattr(module, class_name) if class_name else module


def plugin_table():
    """Return ``{kind: {name: "mi_plugins.folder.module:Class"}}`` for every plugin."""
    table = {}
    for folder, kind in KINDS.items():
        pkg = importlib.import_module("mi_plugins." + folder)
        table[kind] = {name: "mi_plugins.%s.%s" % (folder, target)
                       for name, target in getattr(pkg, "PLUGINS", {}).items()}
    return table


def register_all(variant):
    for folder in KINDS:
        pkg = importlib.import_module("mi_plugins." + folder)
        for base in getattr(pkg, "BASES", []):
            _plugin_class(base if "." in base else "mi_plugins.%s.%s" % (folder, base), None, variant)
    registered = {}
    for kind, plugins in plugin_table().items():
        register_fn = getattr(mi, "register_" + kind)
        for name, target in plugins.items():
            module_name, class_name = target.split(":")
            cls = _plugin_class(module_name, class_name, variant)
            cls.plugin = name        # the one place a plugin's name is written: its folder's PLUGINS
            register_fn(name, lambda props, cls=cls: cls(props))
            registered.setdefault(kind, []).append(name)
    return registered
