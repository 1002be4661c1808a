"""Mitsuba bsdf plugins of mi_plugins (installed as `mi_plugins.bsdfs`).

`PLUGINS` maps each Mitsuba plugin name to "module:Class" inside this folder;
`mi_plugins.register()` registers them for the active variant.
"""

PLUGINS = {
    "phong": "phong:PhongBSDF",
    "separable": "separable:SeparableBSDF",
}
