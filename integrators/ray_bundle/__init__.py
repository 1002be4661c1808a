"""Stochastic iteration with global ray bundles (Szirmay-Kalos, "Stochastic Iteration for
Non-diffuse Global Illumination", sections 5 and 6), one concept per module:

- :mod:`.integrator`: the plugin's parameters;
- :mod:`.run`: one render: set-up, the iterations, the extended burn-in, the final gathering;
- :mod:`.frozen`: the iteration and camera-pass steps traced once and replayed (``dr.freeze``);
- :mod:`.checks`: what is refused before any work (null lobes, delta and transmitting surfaces, shapes);
- :mod:`.limits`: every size of a render against the memory and the documented maxima;
- :mod:`.convergence`: the chains' power, and the bias of an average taken too early;
- :mod:`.directions`: the global directions (sequences, stratified sets, rotations), a block at a time;
- :mod:`.transfer`: chain layout, bounding sphere, line walking, point sources, reflection;
- :mod:`.estimators`: the image estimates ('gather', 'patch') and their sources;
- :mod:`.average`: the per-triangle averages of ``average_diffuse``;
- :mod:`.direct`: ``first_shot``'s direct light of diffuse patches, shared by the chains;
- :mod:`.sharing`: ``share_diffuse``'s reflected radiance of diffuse patches, shared by the chains;
- :mod:`.split`: one render split into chain and gathering tasks (distributed rendering).
"""
from mi_plugins.integrators.ray_bundle.integrator import RayBundleIntegrator  # noqa: F401
