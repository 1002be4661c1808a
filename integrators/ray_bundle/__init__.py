"""Stochastic iteration with global ray bundles (Szirmay-Kalos, "Stochastic Iteration for
Non-diffuse Global Illumination", sections 5 and 6), one concept per module:

- :mod:`.integrator`: the plugin's parameters and the iteration loop;
- :mod:`.directions`: the global directions (sequences, stratified sets, rotations);
- :mod:`.transfer`: chain layout, bounding sphere, line walking, reflection;
- :mod:`.estimators`: the image estimates ('gather', 'patch') and their sources;
- :mod:`.average`: the per-triangle averages of ``average_diffuse``;
- :mod:`.direct`: ``first_shot``'s direct light of diffuse patches, shared by the chains;
- :mod:`.split`: one render split into chain and gathering tasks (distributed rendering).
"""
from mi_plugins.integrators.ray_bundle.integrator import RayBundleIntegrator  # noqa: F401
