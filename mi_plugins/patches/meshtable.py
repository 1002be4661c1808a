"""Flat per-patch tables over all shapes of a Mitsuba scene.

Finite-element algorithms (``ray_bundle``, ``qmc_lighttrace``) keep one value per
patch. :class:`MeshTable` numbers the patches of all shapes consecutively (shape after
shape, in ``scene.shapes()`` order): the (sub-)triangles and clusters of small triangles
of meshes, and the cells of the analytic ``rectangle``, ``disk``, ``sphere`` and
``cylinder`` (see :mod:`mi_plugins.patches.tessellation`). A patch is made of *elements*
(:mod:`mi_plugins.patches.mesh_parts`): a triangle, a sub-triangle of a long triangle, or a cell;
a cluster has many. The table maps a surface interaction to its element and patch
(:meth:`MeshTable.locate`, :meth:`MeshTable.patch`: one lookup) and builds surface
interactions at uniformly distributed points of chosen patches (an element chosen in
proportion to its area), so that BSDFs, emitters and textures can be evaluated there.

Radiance is constant per patch in these methods, so the patch size ``h`` is the spatial
resolution of the solution, whatever the modelling: a mesh triangle longer than the
patch size is split into s x s similar sub-triangles (s the smallest level whose
sub-triangles have edges <= sqrt(2) h, so that a right triangle's legs are <= h, as the
analytic shapes' cells; at most :data:`MAX_SPLIT`), triangles much smaller than h are
clustered. A hit finds its sub-triangle from its barycentric coordinates, computed from
``si.p`` in the parent triangle.

Orientation is Mitsuba's: a patch's normal is the one ``si.n`` reports (the winding's,
negated by ``flip_normals``; a cluster's, the area-weighted mean of its triangles').
Build it at the top level of an integrator's ``render()``.
"""

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import fingerprint
from mi_plugins.base.arrays import jit
from mi_plugins.patches import setup_cache, tessellation
from mi_plugins.patches.mesh_parts import MAX_SPLIT, analytic_part, mesh_part, sub_triangles  # noqa: F401
from mi_plugins.base.queries import is_mesh, reflects_on_both_sides
from mi_plugins.patches.normals import require_consistent_normals
from mi_plugins.patches.tessellation import default_patch_size, sub_triangle_coords


class NonMeshShapeError(ValueError):
    """A shape that is not a triangle mesh was given to a triangle-based algorithm."""


def require_meshes(scene, who):
    """Raise NonMeshShapeError naming the first shape that has neither triangles nor a
    patch division (:data:`mi_plugins.patches.tessellation.KINDS`)."""
    for shape in scene.shapes():
        kind = tessellation.shape_kind(shape)
        if not is_mesh(shape) and kind not in tessellation.KINDS:
            raise NonMeshShapeError(
                "%s: shape '%s' (%s) is neither a triangle mesh nor one of the analytic shapes divided into "
                "patches (%s); use a mesh instead (a 'ply'/'obj' file)."
                % (who, shape.id(), kind, ", ".join(sorted(k.lower() for k in tessellation.KINDS))))


def _mesh_arrays(mesh):
    params = mi.traverse(mesh)
    verts = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
    faces = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
    uv = (np.array(params["vertex_texcoords"], dtype=np.float64).reshape(-1, 2)[faces]
          if mesh.has_vertex_texcoords() else None)
    return verts, faces, uv


def _checked_mesh_part(mesh, h, subdivide, cluster, who):
    """The patches of ``mesh`` (:func:`mi_plugins.patches.mesh_parts.mesh_part`), after the check
    that its vertex normals agree with its winding (:mod:`mi_plugins.patches.normals`), both on
    one read of its arrays."""
    verts, faces, uv = _mesh_arrays(mesh)
    require_consistent_normals(mesh, verts, faces, who)
    return mesh_part(verts, faces, uv, mesh.has_flipped_normals(), h, subdivide, cluster)


def _stored_mesh_part(mesh, digest, h, subdivide, cluster, who):
    """:func:`_checked_mesh_part`, kept in the setup cache by the mesh's content digest
    (:mod:`mi_plugins.patches.setup_cache`)."""
    entry = setup_cache.key("mesh part", digest, float(h), bool(subdivide), bool(cluster))
    return setup_cache.cached(entry, lambda: _checked_mesh_part(mesh, h, subdivide, cluster, who),
                              setup_cache.pack, setup_cache.unpack)


class MeshTable:
    """All patches of ``scene``'s shapes, numbered 0 .. count-1; ``h``: the patch size
    (default: bounding-box diagonal / tessellation.CELLS_PER_DIAGONAL); ``subdivide``:
    split long triangles, ``cluster``: group small ones.

    With ``back_sides``, the surfaces whose BSDF reflects on both sides (``twosided``:
    the BackSide flag with a non-delta lobe) get a second patch per patch, numbered
    ``front_count`` .. count-1: same geometry and surface frame (the BSDF decides by the
    side of ``si.wi``), orientation ``normal`` reversed; :meth:`side_patch` picks the side.

    Per patch (fronts then backs): ``area``, ``normal`` (its side), ``surface_normal``,
    ``shape_index`` (and ``*_np`` numpy copies); per element: ``p0``, ``e1``, ``e2``,
    ``uv0``, ``duv1``, ``duv2``, ``kind``, ``prim``, ``bounds``, ``frame``, ``element_patch``
    (front patch), and the numpy geometry ``elements_np`` of :mod:`mi_plugins.solution.patchfield`."""

    NONE = 0xFFFFFFFF

    def __init__(self, scene, who="mi_plugins", h=None, back_sides=False, subdivide=True, cluster=True, parts=None):
        require_meshes(scene, who)
        self.scene, self.who, self.back_sides = scene, who, back_sides
        self.meshes = self.shapes = list(scene.shapes())
        if h is None:
            h = default_patch_size(scene)
        self.h = float(h)
        if parts is None:
            digests = fingerprint.shape_digests(scene)
            parts = [_stored_mesh_part(m, digest, h, subdivide, cluster, who) if is_mesh(m) else analytic_part(m, h)
                     for m, digest in zip(self.shapes, digests)]
        self.parts = parts                 # numpy, per shape (mi_plugins.patches.mesh_parts), for refined()
        self.dark_rounds = []              # the dark splits that made it (mi_plugins.patches.darkness), kept by refined()
        self.dark_base = None              # the table before them (None: this one)
        self._derived = {}                 # name -> a value made from the geometry (derived())
        self.settings = (bool(subdivide), bool(cluster))
        self.setup_key = None              # the table's name in the setup cache (patches.build), if it has one
        elements = np.array([len(part["area"]) for part in parts], dtype=np.int64)
        patches = np.array([int(part["patch"].max()) + 1 if len(part["patch"]) else 0 for part in parts], np.int64)
        self.face_offsets = np.concatenate([[0], np.cumsum(patches)[:-1]]).astype(np.uint32)
        self.element_offsets = np.concatenate([[0], np.cumsum(elements)[:-1]]).astype(np.int64)
        self.front_count = int(patches.sum())
        self.element_count = int(elements.sum())
        joined = _join(parts, ELEMENT_ARRAYS)
        elem = lambda key: joined[key] if key in joined else np.concatenate([part[key] for part in parts])
        leaf = elem("child") < 0
        element_patch = np.concatenate([np.where(part["patch"] >= 0, part["patch"] + off, -1)
                                        for part, off in zip(parts, self.face_offsets)])
        shape_index = np.repeat(np.arange(len(parts), dtype=np.uint32), patches)
        # per front patch: area, area-weighted normal of its (leaf) elements
        e_area, e_normal = elem("area"), elem("normal")
        on = np.where(leaf, element_patch, 0)
        area = np.bincount(on, np.where(leaf, e_area, 0.0), minlength=self.front_count)
        normal = np.stack([np.bincount(on, np.where(leaf, e_area * e_normal[:, k], 0.0), minlength=self.front_count)
                           for k in range(3)], axis=1)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
        # back sides
        two_sided = np.array([back_sides and reflects_on_both_sides(s) for s in self.shapes], dtype=bool)
        backs = np.flatnonzero(two_sided[shape_index])
        back_of = np.full(self.front_count, self.NONE, dtype=np.uint32)
        back_of[backs] = self.front_count + np.arange(len(backs))
        self._back_of, self.back_of_np = jit(mi.UInt32, back_of), back_of
        #: per patch (fronts, then backs): the front patch it belongs to (backs: their side 1)
        self.front_of_np = np.concatenate([np.arange(self.front_count), backs]).astype(np.int64)
        self.count = self.front_count + len(backs)
        self.areas_np = area[self.front_of_np]
        self.normals_np = normal[self.front_of_np] * np.where(np.arange(self.count) >= self.front_count, -1.0,
                                                              1.0)[:, None]
        self.shape_index_np = shape_index[self.front_of_np]
        #: points whose convex hull holds every patch (triangle vertices, analytic shapes' boxes)
        self.points_np = np.concatenate([part["points"] for part in parts])
        self._lookups(scene, parts, elements)
        self._elements(parts, elem, element_patch, e_area, leaf)
        self.normal = jit(mi.Normal3f, *self.normals_np.T)          # orientation of the patch (its side)
        self.surface_normal = jit(mi.Normal3f, *normal[self.front_of_np].T)   # the surface's (Mitsuba's si.n)
        self.area = jit(mi.Float, self.areas_np)
        self.shape_index = jit(mi.UInt32, self.shape_index_np)
        self._front_of = jit(mi.UInt32, self.front_of_np.astype(np.uint32))

    def _lookups(self, scene, parts, elements):
        """Tables indexed by the shape pointers' ids, and per mesh triangle (all meshes,
        shape after shape): first element, subdivision level, corner and edges."""
        ids = np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), dtype=np.int64)

        def by_id(values):
            table = np.zeros(int(ids.max()) + 1, dtype=np.uint32)
            table[ids] = values
            return jit(mi.UInt32, table)
        meshes = [(i, part) for i, part in enumerate(parts) if "level" in part]
        base = np.concatenate([[0], np.cumsum([len(part["level"]) for _, part in meshes])]).astype(np.int64)
        parent_base = np.zeros(len(parts), dtype=np.int64)
        # two placeholder entries: a width-1 array would enter kernels as a scalar whose
        # memory alignment (different at every allocation) changes the kernel's code, and
        # with it the kernel cache key: a recompilation at almost every render
        first, level, corners = [np.zeros(2, np.int64)], [np.ones(2, np.int64)], [np.zeros((2, 3, 3))]
        for (index, part), b in zip(meshes, base):   # one entry per mesh (not per triangle)
            parent_base[index] = b
            first.append(self.element_offsets[index] + part["first"])
            level.append(part["level"])
            corners.append(part["parents"])
        first, level, corners = (np.concatenate(a[1:] + a[:1]) for a in (first, level, corners))
        self._first = jit(mi.UInt32, first)
        self._level = jit(mi.UInt32, level)
        self._parent_p0 = jit(mi.Point3f, *corners[:, 0].T)
        self._parent_e1 = jit(mi.Vector3f, *(corners[:, 1] - corners[:, 0]).T)
        self._parent_e2 = jit(mi.Vector3f, *(corners[:, 2] - corners[:, 0]).T)
        self._element_by_id = by_id(self.element_offsets)
        self._parent_by_id = by_id(parent_base)
        self._kind_by_id = by_id([p["kind"][0] if len(p["kind"]) else 0 for p in parts])
        self._nu_by_id = by_id([p["nu"] for p in parts])
        self._nv_by_id = by_id([p["nv"] for p in parts])

    def _elements(self, parts, elem, element_patch, e_area, leaf):
        """Per element: geometry for kernels and its first child (split elements); per front
        patch: its leaf elements sorted, with the cumulative share of its area (choosing an
        element uniformly in area); ``elem(key)``: the per-element array ``key`` of all parts."""
        tri, uv, kind = elem("triangle"), elem("uv"), elem("kind")
        # an analytic cell's parameter bounds and shape frame, kept in numpy for the cells
        # only (on meshes they are unused zeros: 200 bytes per triangle)
        cells = np.flatnonzero(kind != 0)
        cell_rows = lambda key: np.concatenate([part[key][part["kind"] != 0] for part in parts])
        bounds, frame = cell_rows("bounds"), cell_rows("frame")
        shape = np.repeat(np.arange(len(parts)), [len(part["area"]) for part in parts])
        child = np.concatenate([np.where(part["child"] >= 0, part["child"] + off, -1)
                                for part, off in zip(parts, self.element_offsets)])
        self.elements_np = dict(triangle=tri, kind=kind, cells=cells, bounds=bounds, frame=frame, area=e_area,
                                normal=elem("normal"), patch=element_patch, centre=elem("centre"), shape=shape,
                                leaf=leaf, depth=elem("depth"))
        #: the most times an element was split (the descent of locate())
        self.max_depth = int(elem("depth").max(initial=0))
        self._child = jit(mi.UInt32, np.where(child >= 0, child, self.NONE).astype(np.uint32))
        self.kind_np = kind
        self.p0, self.e1, self.e2 = jit(mi.Point3f, *tri[:, 0].T), jit(mi.Vector3f, *(tri[:, 1] - tri[:, 0]).T), \
            jit(mi.Vector3f, *(tri[:, 2] - tri[:, 0]).T)
        self.uv0, self.duv1, self.duv2 = jit(mi.Point2f, *uv[:, 0].T), jit(mi.Vector2f, *(uv[:, 1] - uv[:, 0]).T), \
            jit(mi.Vector2f, *(uv[:, 2] - uv[:, 0]).T)
        self.kind = jit(mi.UInt32, kind)
        self.prim = jit(mi.UInt32, elem("prim"))
        # the kernels read them by element, zeros on meshes (arrays of the cells only, read
        # through a row index, crashed a ray_bundle render of a million triangles once
        # Dr.Jit's allocation cache had been flushed between renders: not explained, not kept)
        full_bounds, full_frame = _per_element(len(kind), cells, bounds), _per_element(len(kind), cells, frame)
        self.bounds = tuple(jit(mi.Float, full_bounds[:, k]) for k in range(4))
        self.frame = [jit(mi.Float, full_frame[:, k]) for k in range(full_frame.shape[1])]
        self.element_normal = jit(mi.Normal3f, *elem("normal").T)
        self.element_patch = jit(mi.UInt32, np.where(leaf, element_patch, self.NONE).astype(np.uint32))
        leaves = np.flatnonzero(leaf)
        order = leaves[np.argsort(element_patch[leaves], kind="stable")]
        counts = np.bincount(element_patch[leaves], minlength=self.front_count)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        per_patch = np.bincount(element_patch[leaves], e_area[leaves], minlength=self.front_count)
        share = np.cumsum(e_area[order]) - np.repeat(np.cumsum(per_patch) - per_patch, counts)
        share /= np.maximum(np.repeat(per_patch, counts), 1e-300)
        self._sorted = jit(mi.UInt32, order.astype(np.uint32))
        self._share = jit(mi.Float, share)
        self._patch_first = jit(mi.UInt32, starts.astype(np.uint32))
        self._patch_elements = jit(mi.UInt32, counts.astype(np.uint32))
        #: bisection steps to choose an element of the largest patch
        self.choice_steps = int(np.ceil(np.log2(max(int(counts.max(initial=1)), 1))))

    def side_patch(self, si, toward):
        """The patch of hits ``si`` on the side facing ``toward`` (world directions), and
        whether that side exists (one-sided surfaces have none at the back)."""
        return self.side_of(self.patch(si), si, toward)

    def side_of(self, front, si, toward):
        """:meth:`side_patch` of hits ``si`` whose front patch ``front`` is known."""
        facing = dr.dot(si.n, toward) > 0
        back = dr.gather(mi.UInt32, self._back_of, front, ~facing)
        return dr.select(facing, front, back), facing | (back != self.NONE)

    def derived(self, name, make, stored=None):
        """The value ``name`` that depends on the table's geometry only (the smooth field,
        the bounding sphere of the bundles), made by ``make()`` once and kept with the table:
        a table is not changed once built (a refinement makes a new one), so it never goes
        stale. ``stored``: (to_arrays, from_arrays(arrays, order)), to keep it in the setup
        cache too (:func:`mi_plugins.patches.setup_cache.cached_for_table`; tables built by
        ``patches.build`` only)."""
        if name not in self._derived:
            if stored is not None and self.setup_key is not None:
                entry = setup_cache.key(name, self.setup_key)
                self._derived[name] = setup_cache.cached_for_table(self, entry, make, *stored)
            else:
                self._derived[name] = make()
        return self._derived[name]

    def patch(self, si):
        """Global patch index of the surface interactions ``si`` (valid hits)."""
        return self.locate(si)[0]

    def locate(self, si, active=True):
        """(global front patch, element, mesh, a, b) of hits ``si``: on a mesh element
        (``mesh``) the barycentric coordinates (a, b) of the hit in it (weights of its
        corners 1 and 2), on an analytic cell its fractions (a, b) along u and v."""
        shape_id = dr.reinterpret_array(mi.UInt32, si.shape)
        kind = dr.gather(mi.UInt32, self._kind_by_id, shape_id, active)
        mesh = kind == 0
        nu, nv = dr.gather(mi.UInt32, self._nu_by_id, shape_id, active), dr.gather(mi.UInt32, self._nv_by_id,
                                                                                   shape_id, active)
        iu, iv, fu, fv = tessellation.cell_coords(kind, nu, nv, si.uv)
        base = dr.gather(mi.UInt32, self._element_by_id, shape_id, active)
        parent = dr.gather(mi.UInt32, self._parent_by_id, shape_id, active) + mi.UInt32(si.prim_index)
        on_mesh = mi.Bool(active) & mesh
        level = dr.gather(mi.UInt32, self._level, parent, on_mesh)
        # barycentric coordinates of si.p in the parent triangle (least squares in its plane)
        p0 = dr.gather(mi.Point3f, self._parent_p0, parent, on_mesh)
        e1 = dr.gather(mi.Vector3f, self._parent_e1, parent, on_mesh)
        e2 = dr.gather(mi.Vector3f, self._parent_e2, parent, on_mesh)
        d = si.p - p0
        a11, a12, a22, r1, r2 = dr.dot(e1, e1), dr.dot(e1, e2), dr.dot(e2, e2), dr.dot(d, e1), dr.dot(d, e2)
        det = dr.maximum(a11 * a22 - a12 * a12, 1e-30)
        sub, a, b = sub_triangle_coords(level, (a22 * r1 - a12 * r2) / det, (a11 * r2 - a12 * r1) / det)
        first = dr.gather(mi.UInt32, self._first, parent, on_mesh)
        element = dr.select(mesh, first + sub, base + iv * nu + iu)
        a, b = dr.select(mesh, a, fu), dr.select(mesh, b, fv)
        for _ in range(self.max_depth):     # down the split elements (refinement levels: a few)
            child = dr.gather(mi.UInt32, self._child, element, active)
            split = mi.Bool(active) & (child != self.NONE)
            sub, sa, sb = sub_triangle_coords(2, a, b)
            cu, cv = a >= 0.5, b >= 0.5
            quadrant = dr.select(cv, 2, 0) + dr.select(cu, 1, 0)
            ca, cb = 2.0 * a - dr.select(cu, 1.0, 0.0), 2.0 * b - dr.select(cv, 1.0, 0.0)
            element = dr.select(split, child + dr.select(mesh, sub, quadrant), element)
            a = dr.select(split, dr.select(mesh, sa, ca), a)
            b = dr.select(split, dr.select(mesh, sb, cb), b)
        patch = dr.gather(mi.UInt32, self.element_patch, element, active)
        return patch, element, mesh, a, b

    def refined(self, split):
        """A new table of the same scene with the front patches ``split`` (global indices)
        split (``mi_plugins.patches.mesh_parts.refine``), and (new table, old patch of every new
        front patch: where its elements came from)."""
        from mi_plugins.patches.mesh_parts import refine
        split = np.asarray(split, np.int64)
        owner = self.shape_index_np[:self.front_count]
        parts = [refine(part, split[owner[split] == k] - int(self.face_offsets[k]), self.h) if np.any(owner[split] == k)
                 else part for k, part in enumerate(self.parts)]
        table = MeshTable(self.scene, self.who, h=self.h, back_sides=self.back_sides, parts=parts)
        table.dark_rounds = list(self.dark_rounds)
        origin = np.zeros(table.front_count, np.int64)
        for k, (part, before) in enumerate(zip(parts, self.parts)):
            leaf = part["child"] < 0
            element = np.flatnonzero(leaf)
            ancestor = element.copy()
            for _ in range(int(part["depth"].max(initial=0)) + 1):   # up to an element of the old table
                new = (ancestor >= len(before["area"])) | (ancestor < 0)
                ancestor = np.where(new, part["parent"][np.maximum(ancestor, 0)], ancestor)
            old = before["patch"][ancestor]
            origin[part["patch"][element] + int(table.face_offsets[k])] = old + int(self.face_offsets[k])
        return table, origin

    @property
    def total_area(self):
        return float(self.areas_np.sum())

    def shape_pointer(self, tri):
        """ShapePtr of the shape holding each patch index."""
        idx = dr.gather(mi.UInt32, self.shape_index, tri)
        return dr.gather(mi.ShapePtr, self.scene.shapes_dr(), idx)

    def choose_element(self, tri, u):
        """(element, u rescaled to 0 .. 1 within it) of patches ``tri`` for a uniform number
        ``u``: an element of the patch with probability proportional to its area (bisection
        over the patch's sorted elements: ``choice_steps`` steps)."""
        front = dr.gather(mi.UInt32, self._front_of, tri)
        lo = dr.gather(mi.UInt32, self._patch_first, front)
        hi = lo + dr.gather(mi.UInt32, self._patch_elements, front) - 1
        for _ in range(self.choice_steps):       # (the bisection's steps: a small constant)
            mid = (lo + hi) // 2
            right = dr.gather(mi.Float, self._share, mid) < u
            lo, hi = dr.select(right, mid + 1, lo), dr.select(right, hi, mid)
        upper = dr.gather(mi.Float, self._share, lo)
        lower = dr.select(lo > dr.gather(mi.UInt32, self._patch_first, front),
                          dr.gather(mi.Float, self._share, lo - 1), 0.0)
        rescaled = dr.clip((u - lower) / dr.maximum(upper - lower, 1e-30), 0.0, 0.99999994)
        return dr.gather(mi.UInt32, self._sorted, lo), rescaled

    def surface_interaction(self, tri, sample, wi_world=None):
        """SurfaceInteraction3f at a uniformly distributed point (in area) of each patch
        ``tri`` (UInt32), with position, the surface's normal and frame (Mitsuba's, also
        for back sides), uv, shape and primitive."""
        if self.choice_steps:
            element, u = self.choose_element(tri, sample.x)
            sample = mi.Point2f(u, sample.y)
        else:                # every patch one element: the front patch's own
            element = dr.gather(mi.UInt32, self._sorted, dr.gather(mi.UInt32, self._patch_first,
                                                                    dr.gather(mi.UInt32, self._front_of, tri)))
        g = lambda arr, t: dr.gather(t, arr, element)
        kind = g(self.kind, mi.UInt32)
        analytic = kind != 0
        b = mi.warp.square_to_uniform_triangle(sample)
        p0, e1, e2 = g(self.p0, mi.Point3f), g(self.e1, mi.Vector3f), g(self.e2, mi.Vector3f)
        uv0, duv1, duv2 = g(self.uv0, mi.Point2f), g(self.duv1, mi.Vector2f), g(self.duv2, mi.Vector2f)
        n = g(self.element_normal, mi.Normal3f)
        shape = self.shape_pointer(tri)
        uv = tessellation.sample_cell(kind, tuple(g(x, mi.Float) for x in self.bounds), sample)
        cell_p, cell_n = tessellation.ShapeFrame.apply([g(x, mi.Float) for x in self.frame],
                                                       *tessellation.local_point(kind, uv))
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(tri))
        si.p = dr.select(analytic, cell_p, p0 + e1 * b.x + e2 * b.y)
        si.uv = dr.select(analytic, uv, uv0 + duv1 * b.x + duv2 * b.y)
        si.n = dr.select(analytic, cell_n, n)
        si.sh_frame = mi.Frame3f(si.n)
        si.shape = shape
        si.prim_index = g(self.prim, mi.UInt32)
        si.time = 0.0
        si.t = 0.0
        if wi_world is not None:
            si.wi = si.to_local(wi_world)
        return si


def _per_element(count, cells, rows):
    """(count, k) float64: ``rows`` at the elements ``cells``, zeros elsewhere."""
    out = np.zeros((count,) + rows.shape[1:])
    out[cells] = rows
    return out


#: the per-element arrays of the parts that the table keeps joined (``elements_np``)
ELEMENT_ARRAYS = ("triangle", "uv", "kind", "normal", "centre", "area", "depth", "prim")


def _join(parts, keys):
    """{key: the parts' arrays ``key`` joined}; each part's entry becomes a view of the
    joined array, so that the table and its parts (kept for refinements) hold one copy (on
    a million triangles 190 MB each). Parts are never changed in place (a refinement copies)."""
    joined = {}
    for key in keys:
        joined[key] = np.concatenate([part[key] for part in parts])
        start = 0
        for part in parts:
            n = len(part[key])
            part[key] = joined[key][start:start + n]
            start += n
    return joined
