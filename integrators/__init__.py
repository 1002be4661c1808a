"""Mitsuba integrator plugins of mi_plugins (installed as `mi_plugins.integrators`).

`PLUGINS` maps each Mitsuba plugin name to "module:Class" inside this folder;
`mi_plugins.register()` registers them for the active variant.
"""

PLUGINS = {
    'stochastic_ray': 'stochastic_ray:StochasticRayIntegrator',
    'ray_bundle': 'ray_bundle.integrator:RayBundleIntegrator',
    'qmc_lighttrace': 'qmc_lighttrace.integrator:QMCLightTraceIntegrator',
}

#: modules holding base classes of the plugins above (reloaded first on a variant switch;
#: a dotted name is a module of the package, a plain one a module of this folder)
BASES = ["mi_plugins.render.core", "mi_plugins.solution.integrator"]
