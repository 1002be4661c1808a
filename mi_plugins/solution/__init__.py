"""View-independent solutions of the finite-element integrators: solved once, shown from
any camera, saved and exported.

- :mod:`.solution`: ``Solution`` (the per-patch tables, save/load, export);
  :mod:`.integrator`: ``SolutionIntegrator``, the base of ``ray_bundle`` and
  ``qmc_lighttrace`` (the ``display`` parameter, the solve kept for later renders);
- :mod:`.display`: the display modes (``smooth``, ``patches``, ``baked``);
  :mod:`.patchfield`: the smooth field; :mod:`.gather`, :mod:`.surfaces`: camera paths
  reading the stored light on the patches; :mod:`.patch_light`: the direct light of every
  patch; :mod:`.export`: PLY meshes with baked light; :mod:`.views`: many cameras.

Rule: imports :mod:`mi_plugins.base` .. :mod:`mi_plugins.render` only.
"""
