"""Sampling the scene's light.

- :mod:`.sources`: light rays for the light tracers and next-event estimation, with
  textured area lights sampled uniformly on their shape (Mitsuba's own sampling of them
  is wrong on flipped rectangles and seamed meshes);
- :mod:`.direct`: the direct light of a surface point, light and BSDF samples combined by
  multiple importance sampling.

Rule: imports :mod:`mi_plugins.base` only.
"""
