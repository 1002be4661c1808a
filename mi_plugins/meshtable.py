"""Flat per-patch tables over all shapes of a Mitsuba scene.

Finite-element algorithms (``ray_bundle``, ``qmc_lighttrace``) keep one value per
patch. :class:`MeshTable` numbers the patches of all shapes consecutively (shape after
shape, in ``scene.shapes()`` order): the triangles of meshes, and the cells of the
analytic ``rectangle``, ``disk``, ``sphere`` and ``cylinder`` (see
:mod:`mi_plugins.tessellation`). It maps a surface interaction to its patch
(:meth:`MeshTable.patch`) and builds surface interactions at uniformly distributed
points of chosen patches, so that BSDFs, emitters and textures can be evaluated there.

Radiance is constant per patch in these methods, so the patch size ``h`` is the spatial
resolution of the solution, whatever the modelling: a mesh triangle longer than the
patch size is split into s x s similar sub-triangles (s the smallest level whose
sub-triangles have edges <= sqrt(2) h, so that a right triangle's legs are <= h, as the
analytic shapes' cells; at most :data:`MAX_SPLIT`). A hit finds its sub-triangle from its
barycentric coordinates, computed from ``si.p`` in the parent triangle.

Orientation is Mitsuba's: a patch's normal is the one ``si.n`` reports (the winding's,
negated by ``flip_normals``). Build it at the top level of an integrator's ``render()``.
"""

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import geometry, tessellation


#: subdivision level s (s x s sub-triangles per triangle) at the most
MAX_SPLIT = 64


class NonMeshShapeError(ValueError):
    """A shape that is not a triangle mesh was given to a triangle-based algorithm."""


def _box_corners(bbox):
    lo, hi = np.array(bbox.min, dtype=np.float64), np.array(bbox.max, dtype=np.float64)
    return np.array([[(hi if k >> j & 1 else lo)[j] for j in range(3)] for k in range(8)])


def _reflects_on_both_sides(shape):
    bsdf = shape.bsdf()
    flags = int(bsdf.flags()) if bsdf is not None else 0
    return bool(flags & int(mi.BSDFFlags.BackSide)) and bool(flags & int(mi.BSDFFlags.Smooth))


def _is_mesh(shape):
    return isinstance(shape, mi.Mesh) and "vertex_positions" in mi.traverse(shape).keys()


def require_meshes(scene, who):
    """Raise NonMeshShapeError naming the first shape that has neither triangles nor a
    patch division (:data:`mi_plugins.tessellation.KINDS`)."""
    for shape in scene.shapes():
        kind = tessellation.shape_kind(shape)
        if not _is_mesh(shape) and kind not in tessellation.KINDS:
            raise NonMeshShapeError(
                "%s: shape '%s' (%s) is neither a triangle mesh nor one of the analytic shapes divided into "
                "patches (%s); use a mesh instead (a 'ply'/'obj' file)."
                % (who, shape.id(), kind, ", ".join(sorted(k.lower() for k in tessellation.KINDS))))


class MeshTable:
    """All patches of ``scene``'s shapes, numbered 0 .. count-1; ``h``: the patch size of
    analytic shapes (default: bounding-box diagonal / tessellation.CELLS_PER_DIAGONAL).

    With ``back_sides``, the surfaces whose BSDF reflects on both sides (``twosided``:
    the BackSide flag with a non-delta lobe) get a second patch per patch, numbered
    ``front_count`` .. count-1: same geometry and surface frame (the BSDF decides by the
    side of ``si.wi``), orientation ``normal`` reversed; :meth:`side_patch` picks the side."""

    NONE = 0xFFFFFFFF

    def __init__(self, scene, who="mi_plugins", h=None, back_sides=False, subdivide=True):
        require_meshes(scene, who)
        self.scene = scene
        self.meshes = self.shapes = list(scene.shapes())
        if h is None:
            h = default_patch_size(scene)
        parts = [self._mesh_part(m, h if subdivide else None) if _is_mesh(m) else self._analytic_part(m, h)
                 for m in self.shapes]
        counts = np.array([len(part["area"]) for part in parts], dtype=np.int64)
        self.face_offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.uint32)
        parent_base = self._parent_tables(parts)
        self.front_count = int(counts.sum())
        shape_index = np.repeat(np.arange(len(parts), dtype=np.uint32), counts)
        two_sided = np.array([back_sides and _reflects_on_both_sides(s) for s in self.shapes], dtype=bool)
        backs = np.flatnonzero(two_sided[shape_index])
        back_of = np.full(self.front_count, self.NONE, dtype=np.uint32)
        back_of[backs] = self.front_count + np.arange(len(backs))
        self._back_of = mi.UInt32(back_of)
        #: per patch (fronts, then backs): the front patch it belongs to, and its side (1: back)
        self.front_of_np = np.concatenate([np.arange(self.front_count), backs]).astype(np.int64)
        self.count = self.front_count + len(backs)
        # per-patch arrays: the fronts, then the backs (copies of their fronts)
        cat = lambda key: (lambda a: np.concatenate([a, a[backs]]))(np.concatenate([part[key] for part in parts]))

        ids = np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), dtype=np.int64)

        def by_id(values):       # a lookup table indexed by the shape pointers' ids
            table = np.zeros(int(ids.max()) + 1, dtype=np.uint32)
            table[ids] = values
            return mi.UInt32(table)

        self._offset_by_id = by_id(self.face_offsets)
        self._parent_by_id = by_id(parent_base)
        self._kind_by_id = by_id([p["kind"][0] if len(p["kind"]) else 0 for p in parts])
        self._nu_by_id = by_id([p["nu"] for p in parts])
        self._nv_by_id = by_id([p["nv"] for p in parts])

        self.areas_np = cat("area")
        surface_normals = cat("normal")
        self.normals_np = surface_normals * np.where(np.arange(self.count) >= self.front_count, -1.0, 1.0)[:, None]
        #: points whose convex hull holds every patch (triangle vertices, analytic shapes' boxes)
        self.points_np = np.concatenate([part["points"] for part in parts])
        self.shape_index_np = np.concatenate([shape_index, shape_index[backs]])
        tri = cat("triangle")
        front = slice(0, self.front_count)
        #: numpy geometry of the front patches (mi_plugins.patchfield): corners of mesh
        #: triangles, kind, uv bounds and frame columns of analytic cells
        self.triangles_np, self.kind_np = tri[front], cat("kind")[front]
        self.p0 = mi.Point3f(*tri[:, 0].T)
        self.e1 = mi.Vector3f(*(tri[:, 1] - tri[:, 0]).T)
        self.e2 = mi.Vector3f(*(tri[:, 2] - tri[:, 0]).T)
        uv = cat("uv")
        self.uv0 = mi.Point2f(*uv[:, 0].T)
        self.duv1 = mi.Vector2f(*(uv[:, 1] - uv[:, 0]).T)
        self.duv2 = mi.Vector2f(*(uv[:, 2] - uv[:, 0]).T)
        self.kind = mi.UInt32(cat("kind"))
        self.prim = mi.UInt32(cat("prim"))
        bounds = cat("bounds")
        self.bounds = tuple(mi.Float(bounds[:, k]) for k in range(4))
        frame = cat("frame")
        self.bounds_np, self.frame_np = bounds[front], frame[front]
        self.frame = [mi.Float(frame[:, k]) for k in range(frame.shape[1])]
        self.normal = mi.Normal3f(*self.normals_np.T)          # orientation of the patch (its side)
        self.surface_normal = mi.Normal3f(*surface_normals.T)   # the surface's (Mitsuba's si.n)
        self.area = mi.Float(self.areas_np)
        self.shape_index = mi.UInt32(self.shape_index_np)

    def _parent_tables(self, parts):
        """Per mesh triangle (all meshes, shape after shape): first patch, subdivision
        level, corner and edges; returns each shape's first triangle there."""
        meshes = [(i, part) for i, part in enumerate(parts) if "level" in part]
        sizes = [len(part["level"]) for _, part in meshes]
        base = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        parent_base = np.zeros(len(parts), dtype=np.int64)
        # two placeholder entries: a width-1 array would enter kernels as a scalar whose
        # memory alignment (different at every allocation) changes the kernel's code, and
        # with it the kernel cache key: a recompilation at almost every render
        first, level, corners = [np.zeros(2, np.int64)], [np.ones(2, np.int64)], [np.zeros((2, 3, 3))]
        for (index, part), b in zip(meshes, base):   # one entry per mesh (not per triangle)
            parent_base[index] = b
            first.append(self.face_offsets[index] + part["first"])
            level.append(part["level"])
            corners.append(part["parents"])
        # the placeholder entries last: never empty (gathers need an array)
        first, level, corners = (np.concatenate(a[1:] + a[:1]) for a in (first, level, corners))
        self._first = mi.UInt32(first)
        self._level = mi.UInt32(level)
        self._parent_p0 = mi.Point3f(*corners[:, 0].T)
        self._parent_e1 = mi.Vector3f(*(corners[:, 1] - corners[:, 0]).T)
        self._parent_e2 = mi.Vector3f(*(corners[:, 2] - corners[:, 0]).T)
        return parent_base

    def side_patch(self, si, toward):
        """The patch of hits ``si`` on the side facing ``toward`` (world directions), and
        whether that side exists (one-sided surfaces have none at the back)."""
        front = self.patch(si)
        facing = dr.dot(si.n, toward) > 0
        back = dr.gather(mi.UInt32, self._back_of, front, ~facing)
        return dr.select(facing, front, back), facing | (back != self.NONE)

    @staticmethod
    def _mesh_part(mesh, h):
        """Patches of a mesh: its triangles, each split into level^2 sub-triangles
        (level 1 where ``h`` is None or the triangle is short)."""
        params = mi.traverse(mesh)
        verts = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
        faces = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
        p = verts[faces]
        if mesh.has_vertex_texcoords():
            uv = np.array(params["vertex_texcoords"], dtype=np.float64).reshape(-1, 2)[faces]
        else:
            uv = np.tile(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), (len(faces), 1, 1))
        cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        if mesh.has_flipped_normals():      # Mitsuba's orientation: flip_normals negates the winding's
            cross = -cross
        area = 0.5 * np.linalg.norm(cross, axis=1)
        normal = cross / np.maximum(2 * area[:, None], 1e-30)
        level = split_levels(p, h)
        count = level * level
        parent = np.repeat(np.arange(len(faces)), count)
        bary = np.concatenate([sub_triangles(s)[None].repeat(n, 0).reshape(-1, 3, 2)
                               for s, n in _runs(level)]) if len(faces) else np.zeros((0, 3, 2))
        weights = np.stack([1 - bary[..., 0] - bary[..., 1], bary[..., 0], bary[..., 1]], axis=-1)   # (n, 3, 3)
        tri = np.einsum("nkc,ncd->nkd", weights, p[parent])
        tuv = np.einsum("nkc,ncd->nkd", weights, uv[parent])
        n = len(parent)
        return dict(kind=np.zeros(n, np.uint32), prim=parent.astype(np.uint32), nu=0, nv=0,
                    area=(area / count)[parent], normal=normal[parent], triangle=tri, uv=tuv, bounds=np.zeros((n, 4)),
                    frame=np.zeros((n, 21)), points=p.reshape(-1, 3), parents=p, level=level,
                    first=np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64))

    @staticmethod
    def _analytic_part(shape, h):
        cells = tessellation.ShapePatches(shape, h)
        n = cells.count
        return dict(kind=np.full(n, cells.kind, np.uint32), prim=np.zeros(n, np.uint32), nu=cells.nu, nv=cells.nv,
                    area=cells.areas, normal=cells.normals, triangle=np.zeros((n, 3, 3)), uv=np.zeros((n, 3, 2)), bounds=cells.bounds,
                    frame=np.tile(cells.frame.columns, (n, 1)), points=_box_corners(shape.bbox()))

    def patch(self, si):
        """Global patch index of the surface interactions ``si`` (valid hits)."""
        return self.locate(si)[0]

    def locate(self, si, active=True):
        """(global patch index, mesh, a, b) of hits ``si``: on a mesh patch (``mesh``) the
        barycentric coordinates (a, b) of the hit in it (weights of its corners 1 and 2),
        on an analytic cell its fractions (a, b) along u and v."""
        shape_id = dr.reinterpret_array(mi.UInt32, si.shape)
        kind = dr.gather(mi.UInt32, self._kind_by_id, shape_id, active)
        mesh = kind == 0
        nu, nv = dr.gather(mi.UInt32, self._nu_by_id, shape_id, active), dr.gather(mi.UInt32, self._nv_by_id,
                                                                                   shape_id, active)
        iu, iv, fu, fv = tessellation.cell_coords(kind, nu, nv, si.uv)
        cell = dr.gather(mi.UInt32, self._offset_by_id, shape_id, active) + iv * nu + iu
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
        return dr.select(mesh, first + sub, cell), mesh, dr.select(mesh, a, fu), dr.select(mesh, b, fv)

    @property
    def total_area(self):
        return float(self.areas_np.sum())

    def shape_pointer(self, tri):
        """ShapePtr of the mesh holding each triangle index."""
        idx = dr.gather(mi.UInt32, self.shape_index, tri)
        return dr.gather(mi.ShapePtr, self.scene.shapes_dr(), idx)

    def surface_interaction(self, tri, sample, wi_world=None):
        """SurfaceInteraction3f at a uniformly distributed point (in area) of each patch
        ``tri`` (UInt32), with position, the surface's normal and frame (Mitsuba's, also
        for back sides), uv, shape and primitive."""
        g = lambda arr, t: dr.gather(t, arr, tri)
        kind = g(self.kind, mi.UInt32)
        analytic = kind != 0
        b = mi.warp.square_to_uniform_triangle(sample)
        p0, e1, e2 = g(self.p0, mi.Point3f), g(self.e1, mi.Vector3f), g(self.e2, mi.Vector3f)
        uv0, duv1, duv2 = g(self.uv0, mi.Point2f), g(self.duv1, mi.Vector2f), g(self.duv2, mi.Vector2f)
        n = g(self.surface_normal, mi.Normal3f)
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


#: the patch table of the last render (one entry for every integrator of the process): a
#: display renders many views of one scene, and a table of a million triangles takes
#: seconds to build. Held here, not by an integrator, which its scene holds (a reference
#: cycle through C++ would keep every scene alive); this keeps the last scene alive only
_LAST = []


def cached_table(scene, who, h, back_sides=False, subdivide=True):
    """The :class:`MeshTable` of ``scene`` with these settings, built again only when the
    scene object, its content (``mi_plugins.fingerprint``) or the settings differ from the
    last call's."""
    from mi_plugins.fingerprint import scene_fingerprint
    key = (id(scene), scene_fingerprint(scene), float(h), bool(back_sides), bool(subdivide))
    if not _LAST or _LAST[0][0] != key:
        _LAST[:] = [(key, MeshTable(scene, who, h=h, back_sides=back_sides, subdivide=subdivide))]
    return _LAST[0][1]


def patch_parameters(p):
    """The patch parameters of a finite-element integrator, read with Params ``p``:
    ``patch_size`` (None: :func:`default_patch_size`) and ``subdivide``."""
    size = p.float("patch_size", None, lo=0, lo_open=True, note="optional: default scene diagonal / %d"
                   % tessellation.CELLS_PER_DIAGONAL)
    return size, p.bool("subdivide", True)


def default_patch_size(scene):
    """The scene's bounding-box diagonal (:func:`scene_bounds`) / tessellation.CELLS_PER_DIAGONAL."""
    lo, hi = scene_bounds(scene)
    return float(np.linalg.norm(hi - lo)) / tessellation.CELLS_PER_DIAGONAL


def scene_bounds(scene):
    """(min, max) corners (numpy float64) of the box around every shape of ``scene``.

    Not ``scene.bbox()``: ``mi.load_dict`` (optimize=True) merges shapes that share a BSDF
    into one ``Mesh`` whose ``bbox()`` is invalid, and ``scene.bbox()`` leaves it out
    (Mitsuba 3.9.1: two 80 x 80 ``rectangle`` planes with one BSDF vanish from it), so a
    size derived from it can be 5x too small. A mesh with an invalid box is bounded by
    its vertices."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for shape in scene.shapes():
        box = shape.bbox()
        if box.valid():
            points = np.array([box.min, box.max], dtype=np.float64)
        elif _is_mesh(shape):
            points = np.array(mi.traverse(shape)["vertex_positions"], dtype=np.float64).reshape(-1, 3)
        else:
            continue
        if len(points):
            lo, hi = np.minimum(lo, points.min(axis=0)), np.maximum(hi, points.max(axis=0))
    if not np.all(np.isfinite(lo)):
        box = scene.bbox()
        lo, hi = ((np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)) if box.valid()
                  else (np.zeros(3), np.zeros(3)))
    return lo, hi


def split_levels(p, h):
    """Subdivision level per triangle (corners ``p``, (n, 3, 3)): the smallest s with
    longest edge / s <= sqrt(2) h, at most MAX_SPLIT; 1 everywhere when ``h`` is None."""
    if h is None or not len(p):
        return np.ones(len(p), dtype=np.int64)
    edge = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max(axis=1)
    return np.clip(np.ceil(edge / (np.sqrt(2.0) * h) * (1 - 1e-9)), 1, MAX_SPLIT).astype(np.int64)


def sub_triangles(s):
    """Barycentric corners (b1, b2) of the s x s sub-triangles, (s^2, 3, 2), in the order
    of :func:`sub_triangle` (:func:`mi_plugins.geometry.triangle_lattice`)."""
    return geometry.triangle_lattice(s) / float(s)


def sub_triangle(s, b1, b2):
    """Index (see :func:`sub_triangles`) of the sub-triangle holding barycentric
    coordinates (b1, b2) in a triangle split at level ``s`` (JIT arrays)."""
    return sub_triangle_coords(s, b1, b2)[0]


def sub_triangle_coords(s, b1, b2):
    """(index, a, b): the sub-triangle holding (b1, b2) (:func:`sub_triangle`) and the
    barycentric coordinates (a, b) of the point in it (weights of its corners 1 and 2,
    in the order of :func:`sub_triangles`; clamped into the sub-triangle)."""
    x, y = b1 * mi.Float(s), b2 * mi.Float(s)
    j = dr.minimum(mi.UInt32(dr.maximum(y, 0.0)), s - 1)
    i = dr.minimum(mi.UInt32(dr.maximum(x, 0.0)), s - 1 - j)
    fx, fy = x - mi.Float(i), y - mi.Float(j)
    inverted = (fx + fy > 1.0) & (i + j < s - 1)
    a = dr.clip(dr.select(inverted, 1.0 - fx, fx), 0.0, 1.0)
    b = dr.clip(dr.select(inverted, 1.0 - fy, fy), 0.0, 1.0 - a)
    return j * (2 * s - j) + 2 * i + dr.select(inverted, 1, 0), a, b


def _runs(level):
    """(value, run length) of consecutive equal entries of ``level``."""
    if not len(level):
        return []
    cut = np.flatnonzero(np.diff(level)) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [len(level)]])
    return [(int(level[a]), int(b - a)) for a, b in zip(starts, ends)]
