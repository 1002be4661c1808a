"""The foundations every layer of the package uses.

- :mod:`.errors`: ``Unsupported`` (a refused scene feature), ``NotConverged``, ``root_cause``;
- :mod:`.params`: the one parameter reader of every plugin (strict types and ranges, one
  message format); :mod:`.textures`, :mod:`.editable`: the values it reads and keeps valid;
- :mod:`.seeds`: named random streams; :mod:`.sequences`: Halton, Faure, Sobol and their
  scrambles; :mod:`.limits`: memory and lane limits checked before any work;
- :mod:`.queries`: what a scene holds (plugin names, BSDFs, bounds); :mod:`.fingerprint`:
  a scene's content digest; :mod:`.scene_xml`: scene dicts written as XML;
- :mod:`.collection`: garbage collection around renders; :mod:`.render_errors`:
  ``mi.render`` raises the package's errors unwrapped; :mod:`.llvm`: finding libLLVM;
- :mod:`.arrays`: numpy setup helpers (distinct values and rows at the speed of a sort,
  numpy columns in aligned memory so kernels compile once per layout, not per scene).

Rule: imports nothing of the package (and this file imports nothing at all: the package
configures libLLVM through :mod:`.llvm` before Mitsuba is imported).
"""
