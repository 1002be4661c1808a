"""Surfaces divided into patches, the elements of the finite-element integrators.

- :mod:`.meshtable`: ``MeshTable``, every patch of every shape numbered in one table;
  :mod:`.build`: the table of a render (cached per scene and settings) and the patch
  parameters; :mod:`.mesh_parts`, :mod:`.tessellation`: the patches of a mesh (split long
  triangles, clustered small ones) and of the analytic shapes; :mod:`.normals`: meshes
  whose vertex normals contradict their winding;
- :mod:`.darkness`: splits where patches lie partly in the dark or are cut by a surface;
  :mod:`.refinement`: adaptive subdivision where a solution varies within a patch;
  :mod:`.neighbours`: sharing estimates between neighbouring pixels of one patch;
  :mod:`.gaps`: patch sides at the mouth of a gap narrower than a patch;
- :mod:`.setup_cache`: the disk cache of a scene's setup (patches, dark splits, gap
  mouths, the smooth field), keyed by content, reused by later renders and processes.

Rule: imports :mod:`mi_plugins.base` and :mod:`mi_plugins.light` only.
"""
