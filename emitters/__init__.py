"""Mitsuba emitter plugins of mi_plugins (installed as `mi_plugins.emitters`).

`PLUGINS` maps each Mitsuba plugin name to "module:Class" inside this folder;
`mi_plugins.register()` registers them for the active variant.
"""

PLUGINS = {
    "simulated_area": "simulated_area:SimulatedAreaEmitter",
    "directional_area": "directional_area:DirectionalAreaEmitter",
}

#: modules holding base classes of the plugins above (reloaded first on a variant switch)
BASES = ["surface_emitter"]
