"""View-independent solutions of the finite-element integrators.

``ray_bundle`` and ``qmc_lighttrace`` solve for the light *in object space*: what every
patch side receives does not depend on the camera. A :class:`Solution` holds it:

- ``tables`` (T, K, 2, 3): the irradiance each front patch side (side 0: the one its
  normal points to) receives from the light the method carried, RGB, in *read tables*:
  table t holds the light of paths that reach the patch after 2 .. t + 2 segments from
  a light (T = 1 with an unbounded depth: every such path), so that a camera path with
  a finite ``max_depth`` reads exactly the orders it may (``integrators.display.read_table``);
- ``direct`` (K, 2, 3): the direct irradiance (1 segment), estimated per patch side by
  next-event estimation; ``direct_in_tables`` where the method carries it in the tables
  instead (``ray_bundle`` with ``first_shot`` false);
- ``radiance`` (K, 2, 3): the flat outgoing radiance of each patch side along its
  normal (emission + rho / pi (direct + tables[-1]) at the centroid; 0 reflection on
  patches that are not purely diffuse), and ``emission`` (K, 2, 3), its emitted part;
- ``error`` (K, 2, 3): the standard error of ``tables[-1]`` where the method gives one
  (the spread between independent groups of chains or of particles);
- ``meta``: integrator, seed, depth, patch parameters, seconds, iterations or particles,
  the scene's fingerprint and every shape's digest (:mod:`mi_plugins.base.fingerprint`).

``field`` (:class:`mi_plugins.solution.patchfield.PatchField`) holds the patches' vertices for
the smooth display and for :meth:`to_ply`. :meth:`save` / :meth:`load` store it and
give it back for a scene that matches (shape count, triangle and patch counts,
content); a solution is obtained with ``mi_plugins.solve(scene, integrator, seed)``.
:meth:`to_ply`, :meth:`to_gltf` and :meth:`to_html` export its baked radiance.
"""
import io
import json
import os

import numpy as np

from mi_plugins.base import fingerprint
from mi_plugins.patches.setup_cache import block_index

FORMAT = 1
#: what a solution's file holds besides ``meta``
ARRAYS = ("tables", "direct", "radiance", "emission", "error", "areas")


class SolutionMismatch(ValueError):
    """A stored solution does not belong to the scene it is loaded for."""


class Solution:
    """See the module docstring."""

    def __init__(self, tables, areas, meta, error=None, direct_in_tables=False, field=None, direct=None,
                 radiance=None, emission=None):
        optional = lambda a: None if a is None else np.asarray(a, dtype=np.float64)
        self.tables = np.asarray(tables, dtype=np.float64)
        self.direct, self.radiance, self.emission = optional(direct), optional(radiance), optional(emission)
        self.areas = np.asarray(areas, dtype=np.float64)
        self.error = optional(error)
        self.direct_in_tables = bool(direct_in_tables)
        self.meta = dict(meta)
        self.field = field
        self._vertex = {}
        self._arrays = {}

    # ------------------------------------------------------------------ properties
    @property
    def patches(self):
        return self.tables.shape[1]

    @property
    def seed(self):
        return int(self.meta["seed"])

    @property
    def unbounded(self):
        return int(self.meta.get("max_depth", -1)) < 0

    def indirect(self):
        """(K, 2, 3): the irradiance of every path the tables hold (zeros without tables: a
        depth that reads no stored light)."""
        return self.tables[-1] if len(self.tables) else np.zeros((self.patches, 2, 3))

    def total_irradiance(self):
        """(K, 2, 3): direct and carried irradiance together."""
        if self.direct is None or self.direct_in_tables:
            return self.indirect()
        return self.direct + self.indirect()

    def vertex_values(self, name):
        """Vertex values of ``name``, fitted once: 'tables' (T, V, 2, 3), 'radiance',
        'emission', 'direct' (V, 2, 3)."""
        if name not in self._vertex:
            if self.field is None:
                raise ValueError("this solution has no patch geometry: load it with Solution.load(path, scene)")
            values = getattr(self, name)
            if name == "tables":
                self._vertex[name] = np.moveaxis(self.field.fit(np.moveaxis(values, 1, 0)), 0, 1)
            else:
                self._vertex[name] = self.field.fit(values)
        return self._vertex[name]

    def array(self, name, make):
        """An array made from this solution (``make()``, once per name): Dr.Jit arrays for
        kernels, or numpy ones a display derives from it (its steep patches)."""
        if name not in self._arrays:
            self._arrays[name] = make()
        return self._arrays[name]

    def __repr__(self):
        m = self.meta
        how = ("%d iterations x %d chains" % (m.get("iterations", 0), m.get("chains", 0)) if "chains" in m
               else "%d particle paths" % m.get("paths", 0))
        return ("Solution[%s, %d patches, %d table(s), %s, seed %d, %.3g s]"
                % (m.get("integrator"), self.patches, self.tables.shape[0], how, self.seed, m.get("seconds", 0.0)))

    def complete(self, scene, table):
        """Compute what is made on demand, for ``scene`` and its patch ``table``: the patch
        geometry (``field``), the direct irradiance and the flat radiance of every patch side."""
        from mi_plugins.solution.patchfield import field_of
        from mi_plugins.solution import patch_light
        if self.field is None:
            self.field = field_of(table)
        if self.direct is None:
            self.direct, _ = patch_light.direct_irradiance(scene, table, self.seed)
        if self.radiance is None or self.emission is None:
            f, self.emission = patch_light.side_values(scene, table)
            self.radiance = self.emission + f * self.total_irradiance()
        return self

    # ------------------------------------------------------------------ matching a scene
    def check_scene(self, scene):
        """Raise SolutionMismatch unless ``scene`` has the shapes and content this solution
        was computed for; returns each stored shape's index in ``scene.shapes()``."""
        shapes = self.meta["shapes"]
        digests = fingerprint.shape_digests(scene)
        if len(digests) != len(shapes):
            raise SolutionMismatch("solution of '%s': it was computed for a scene of %d shapes; this scene has %d"
                                   % (self.meta.get("integrator"), len(shapes), len(digests)))
        free = {}
        for index, digest in enumerate(digests):
            free.setdefault(digest, []).append(index)
        order = []
        for stored in shapes:
            if not free.get(stored["digest"]):
                raise SolutionMismatch(
                    "solution of '%s': the scene has no shape matching its shape '%s' (%s, %d triangles): the "
                    "geometry, transform, material or emission differs (content fingerprint); solve the scene "
                    "again" % (self.meta.get("integrator"), stored["id"], stored["class"], stored["triangles"]))
            order.append(free[stored["digest"]].pop(0))
        if fingerprint.scene_fingerprint(scene) != self.meta["fingerprint"]:
            raise SolutionMismatch("solution of '%s': the scene's emitters or content differ from the scene it "
                                   "was computed for (content fingerprint); solve the scene again"
                                   % self.meta.get("integrator"))
        return order

    # ------------------------------------------------------------------ files
    def save(self, path):
        """Write the solution to ``path`` (a file name or a binary file object; a NumPy
        ``.npz`` archive; the patch geometry is rebuilt from the scene when loading)."""
        arrays = {name: getattr(self, name) for name in ARRAYS if getattr(self, name) is not None}
        meta = dict(self.meta, format=FORMAT, direct_in_tables=self.direct_in_tables)
        data = dict(meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
        if hasattr(path, "write"):
            np.savez_compressed(path, **data)
            return path
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        with open(path, "wb") as f:
            np.savez_compressed(f, **data)
        return path

    def to_bytes(self):
        """The solution as the bytes of its file (to ship it to other processes)."""
        buffer = io.BytesIO()
        self.save(buffer)
        return buffer.getvalue()

    @classmethod
    def from_bytes(cls, data, scene):
        """:meth:`load` from the bytes of :meth:`to_bytes`."""
        return cls.load(io.BytesIO(data), scene)

    @classmethod
    def load(cls, path, scene):
        """The solution stored in ``path``, for ``scene`` (refused with SolutionMismatch when
        the scene does not match: shape count, each shape's triangles, patches and
        content), its patches in ``scene``'s order."""
        with np.load(path) as data:
            meta = json.loads(bytes(data["meta"]).decode())
            arrays = {name: data[name] for name in ARRAYS if name in data}
        if meta.get("format") != FORMAT:
            raise SolutionMismatch("%s: solution format %s; this version reads format %d"
                                   % (path, meta.get("format"), FORMAT))
        return cls._homed(arrays, meta, meta.get("direct_in_tables", False), scene, path)

    def for_scene(self, scene):
        """This solution with its patches numbered as ``scene``'s: itself where ``scene``
        lists the shapes in the order of the scene it was solved for, else a copy in
        ``scene``'s order (Mitsuba may load the shapes of one file in another order each
        time); refused with SolutionMismatch as :meth:`load` for another scene."""
        if [s["digest"] for s in self.meta["shapes"]] == fingerprint.shape_digests(scene):
            return self
        arrays = {name: getattr(self, name) for name in ARRAYS if getattr(self, name) is not None}
        meta = json.loads(json.dumps(self.meta))
        return type(self)._homed(arrays, meta, self.direct_in_tables, scene, "solution")

    @classmethod
    def _homed(cls, arrays, meta, direct_in_tables, scene, where):
        """A solution of ``arrays`` and ``meta`` (the patches in the order of ``meta['shapes']``),
        renumbered for ``scene`` and its patch geometry rebuilt."""
        from mi_plugins.patches.meshtable import MeshTable
        from mi_plugins.solution.patchfield import field_of
        solution = cls(arrays["tables"], arrays["areas"], meta, arrays.get("error"), direct_in_tables,
                       direct=arrays.get("direct"), radiance=arrays.get("radiance"), emission=arrays.get("emission"))
        order = solution.check_scene(scene)
        from mi_plugins.patches.darkness import renumbered, split_in_the_dark
        base = MeshTable(scene, meta.get("integrator", "solution"), h=meta["patch_size"],
                         subdivide=meta["subdivide"], cluster=meta.get("cluster", True))
        # the recorded dark splits and refinements, in this scene's numbering of the patches
        # (its shapes may load in another order); a file without dark splits: measured again
        if "dark_splits" in meta:
            meta["dark_splits"], dark = renumbered(base, meta["dark_splits"], order)
            if dark is not base:
                dark.dark_base = base
        else:
            dark = split_in_the_dark(base, meta.get("dark_levels", 0))
        meta["refinements"], table = renumbered(dark, meta.get("refinements") or [], order,
                                                 lambda t, split: t.refined(split)[0])
        solution.meta.update({k: meta[k] for k in ("dark_splits", "refinements") if k in meta})
        counts = np.bincount(table.shape_index_np[:table.front_count], minlength=len(order))
        for stored, index in zip(meta["shapes"], order):
            if counts[index] != stored["patches"]:
                raise SolutionMismatch("%s: shape '%s' has %d patches here and %d in the solution"
                                       % (where, stored["id"], counts[index], stored["patches"]))
        solution._reorder(order, table)
        solution.field = field_of(table)
        return solution

    def _reorder(self, order, table):
        """Put the patches (stored shape after shape) in the order of ``table``'s shapes."""
        shapes = self.meta["shapes"]
        counts = np.bincount(table.shape_index_np[:table.front_count], minlength=len(order))
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        index = block_index(offsets, counts, order)    # (load checked the stored counts are these)
        self.tables = self.tables[:, index]
        for name in ("direct", "radiance", "emission", "error", "areas"):
            if getattr(self, name) is not None:
                setattr(self, name, getattr(self, name)[index])
        self.meta["shapes"] = [shapes[order.index(i)] for i in range(len(order))]

    def to_ply(self, folder, display_colors=False):
        """Write every shape as a binary PLY mesh with its per-vertex radiance as the
        float vertex properties r, g, b (side 0; back_r, back_g, back_b: side 1), which
        Mitsuba reads back as the ``vertex_color`` attribute (``mesh_attribute`` texture);
        ``display_colors`` adds 8-bit sRGB colours for mesh viewers
        (:mod:`mi_plugins.solution.export`). Returns the paths."""
        from mi_plugins.solution.export import write_meshes
        return write_meshes(self, folder, display_colors)

    def to_gltf(self, path):
        """Write every shape with its per-vertex radiance as one glTF 2.0 file (``.glb`` or
        ``.gltf``): ``COLOR_0`` linear, scaled into [0, 1] by the ``radiance_scale`` its
        ``extras`` state; ``_RADIANCE`` the HDR radiance (:mod:`mi_plugins.solution.gltf`).
        Returns the path."""
        from mi_plugins.solution.gltf import write_gltf
        return write_gltf(self, path)

    def to_html(self, path, scene, sensor=0, exposure=0.0):
        """Write a self-contained HTML page (WebGL 2, no network) that shows the baked
        radiance from a walkthrough camera starting at ``scene``'s sensor ``sensor``, at
        ``exposure`` stops (-20 .. 20; default 0: the PNG writer's tone curve)
        (:mod:`mi_plugins.solution.viewer`). ``scene``: the solution's scene. Returns the path."""
        from mi_plugins.solution.viewer import write_html
        return write_html(self, path, scene, sensor, exposure)
