"""Mitsuba sampler plugins of mi_plugins (installed as `mi_plugins.samplers`).

`PLUGINS` maps each Mitsuba plugin name to "module:Class" inside this folder;
`mi_plugins.register()` registers them for the active variant.
"""

PLUGINS = {
    "halton": "halton:HaltonSampler",
    "sobol": "sobol:SobolSampler",
    "faure": "faure:FaureSampler",
    "padded_sobol": "padded_sobol:PaddedSobolSampler",
    "zsobol": "zsobol:ZSobolSampler",
    "lattice": "lattice:LatticeSampler",
    "cmj": "cmj:CMJSampler",
}

#: modules holding base classes of the plugins above (reloaded first on a variant switch)
BASES = ["sequence_sampler", "padded_sobol"]
