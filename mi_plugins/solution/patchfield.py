"""Smooth fields over patches: per-vertex values from patch averages, and their
interpolation at surface points.

A finite-element solution holds one value per patch side: the patch's average. The
smooth display and the exported meshes show the field reconstructed from them:

- **vertices**: the corners of the patches (mesh triangles and their sub-triangles; the
  uv corners of the cells of analytic shapes), welded where they coincide in space and
  the patches' normals agree within :data:`WELD_ANGLE` (a crease, e.g. a floor meeting a
  wall, keeps a vertex per surface), across sub-triangles, triangles and shapes alike,
  except across a surface standing on them (:func:`separate`: a panel on a floor) and
  between a patch at a narrow gap's mouth and the others (:mod:`mi_plugins.patches.gaps`: its
  value mixes the gap's trapped light with the open side's and is never read);
- **vertex values**: at each vertex, an area-weighted least-squares plane through the
  values of the patches that share it, taken at their centroids, evaluated at the
  vertex; where those do not span the plane (the corner of a quad, the inside of a
  cluster), through the patches adjacent to them too (exact for a field linear in
  position on a flat surface, at interior, border and corner vertices alike; the
  area-weighted mean only where even those do not span it); then :data:`CONSERVE_ITERATIONS`
  corrections that move each vertex by the mean residual of its patches (the patch's
  value minus the average of the field interpolated over it, weighted by the vertex's
  share of that average): where the field bends within a few patches (near a lamp, in
  corners, beside a shadow) the planes round the bend off and the interpolated patch
  averages drift from the patch values (the image mean -2.6 % in a room lit through its
  ceiling); the corrections bring them back (-0.86 %) and leave a linear field as it
  is. Before each correction the limiter (:mod:`mi_plugins.solution.limiter`) keeps a
  vertex its patches surround within their values and any other at or above 0 where
  they are: a linear field without negative values is untouched, the gross overshoot
  beside a steep change is cut (a lit strip on a shadowed floor: +547 % -> +6 %), and the
  corrections take back what it moved where the light is merely noisy. Elsewhere a
  vertex value is a fixed linear combination of patch values, so unbiased patch values
  give unbiased vertex values (clamping every vertex at 0 after the corrections was
  tried and biased the caustic of the conformance suite's ``mirror_lit`` by +4 %, z +10;
  the corrections can take a vertex beside a steep drop below 0);
- **interpolation**: a point of a triangle patch takes its barycentric combination of
  the three vertex values, a point of an analytic cell the bilinear one in its (u, v).

Values are arrays (K, C) over the front patches of a :class:`mi_plugins.patches.meshtable.MeshTable`
(any C channels: sides, RGB, tables); :class:`PatchField` fits them (numpy, vectorised
over vertices) and :meth:`PatchField.weights` gives, inside kernels, the four vertex
indices and weights of each hit located by ``MeshTable.locate``.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base.arrays import distinct, jit
from mi_plugins.patches import darkness, setup_cache, tessellation
from mi_plugins.patches.gaps import mouth_patches
from mi_plugins.solution import limiter

#: patches whose normals differ by more than this (degrees) at a shared corner keep
#: vertices of their own
WELD_ANGLE = 45.0
#: corners closer than this (relative to the scene's extent) are one vertex
WELD_TOLERANCE = 1e-6
#: a vertex's least-squares plane needs its normal matrix's smallest eigenvalue above
#: this share of its trace (else the area-weighted mean)
MIN_SPREAD = 1e-3
#: corrections of the vertex values toward the patch averages (each moves a vertex by the
#: mean residual of its patches): 2 take most of the bias away (room lit through its
#: ceiling: -2.6 % -> -0.86 %, 4: -0.81 %), more follow the patches' noise (Cornell box,
#: qmc_lighttrace: RMSE away from the lamp +0.4 % at 2, +11 % at 4)
CONSERVE_ITERATIONS = 2


def _analytic_corners(kind, cells, bounds, frame):
    """(C, 4, 3) world corners (u0, v0), (u1, v0), (u0, v1), (u1, v1) of the analytic cells
    ``cells`` (element indices; ``bounds``, ``frame``: one row per cell) among elements of
    ``kind``."""
    corners = np.zeros((len(cells), 4, 3))
    if not len(cells):
        return corners
    u0, u1, v0, v1 = (bounds[:, j] for j in range(4))
    columns = [mi.Float(frame[:, j]) for j in range(frame.shape[1])]
    for j, (u, v) in enumerate(zip([u0, u1, u0, u1], [v0, v0, v1, v1])):
        uv = mi.Point2f(mi.Float(u), mi.Float(v))
        p, _ = tessellation.ShapeFrame.apply(columns, *tessellation.local_point(mi.UInt32(kind[cells]), uv))
        corners[:, j] = np.array(p, dtype=np.float64).T.reshape(-1, 3)
    return corners


def weld(points, normals, scale, angle=WELD_ANGLE):
    """(vertex index (N,), the first corner of that vertex (N,)) of each corner ``points``
    (N, 3) with patch normal ``normals`` (N, 3): corners within WELD_TOLERANCE x ``scale``
    share a vertex when their normals are within ``angle`` degrees of the first normal of
    the group (greedy rounds; a vertex's first corner leads it)."""
    n = len(points)
    if not n:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    cell = max(float(scale), 1e-30) * WELD_TOLERANCE * 4
    keys = np.round(points / cell).astype(np.int64)
    keys -= keys.min(axis=0)
    span = keys.max(axis=0) + 1
    if float(np.prod(span.astype(np.float64))) < 2.0 ** 62:    # one integer per cell: a flat sort
        _, first, group = np.unique((keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2],
                                    return_index=True, return_inverse=True)
    else:
        _, first, group = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    group = group.ravel()
    vertex, first_corner = np.full(n, -1, np.int64), np.zeros(n, np.int64)
    cos_limit, next_id = np.cos(np.radians(angle)), 0
    size = len(first)
    left, groups = np.arange(n), np.arange(size)     # (the first round: every corner, every group)
    while True:          # a few rounds: one per distinct normal at a point
        if next_id:
            left = np.flatnonzero(vertex < 0)
            if not len(left):
                return vertex, first_corner
            groups, first = np.unique(group[left], return_index=True)
        leader = np.full(size, -1, np.int64)
        leader[groups] = left[first]
        lead = leader[group[left]]
        join = np.einsum("ij,ij->i", normals[left], normals[lead]) >= cos_limit
        join |= left == lead
        ids = np.full(size, -1, np.int64)
        ids[groups] = next_id + np.arange(len(groups))
        vertex[left[join]] = ids[group[left[join]]]
        first_corner[left[join]] = lead[join]
        next_id += len(groups)


def separate(scene, vertex, centres, normals, scale, lead):
    """``vertex`` (N,) with the corners whose element a surface standing on the patches
    separates from the vertex's first element given a vertex of their own: the segment
    between the two elements' centres, just off their surface, meets a surface steeper
    than 30 degrees to them (a panel standing on a floor whose elements run under it:
    the floor's field on either side is fitted from that side's patches, instead of
    carrying the lit side's light across the panel's line). ``lead``: each corner's
    vertex's first corner, as :func:`weld` gives it."""
    n = len(vertex)
    if not n:
        return vertex
    eps = 1e-5 * (1.0 + float(scale))
    apart = np.array(darkness.crossed(scene, jit(mi.Point3f, *(centres + normals * eps).T),
                                      jit(mi.Point3f, *(centres[lead] + normals[lead] * eps).T),
                                      jit(mi.Vector3f, *normals.T)), dtype=bool)
    if not apart.any():
        return vertex
    return np.unique(vertex * 2 + apart, return_inverse=True)[1].ravel()


#: the entries (i, j), i <= j, of a symmetric 3 x 3 matrix, in the order _inverses reads them
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _tangents(normals):
    """Two unit tangents (n, 3) each of the directions ``normals`` (normalised here)."""
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(n, helper)
    t1 /= np.maximum(np.linalg.norm(t1, axis=1, keepdims=True), 1e-30)
    return t1, np.cross(n, t1)


def _inverses(entries):
    """(inverses (n, 3, 3), invertible (n,)) of symmetric 3 x 3 matrices given by their
    upper entries (n, 6) (order _UPPER), by cofactors; invertible where the determinant
    is not tiny against the matrix's size cubed (its smallest eigenvalue not tiny
    against its trace: MIN_SPREAD); zeros elsewhere."""
    a, b, c, d, e, f = entries.T
    cof = np.stack([d * f - e * e, c * e - b * f, b * e - c * d, a * f - c * c, b * c - a * e, a * d - b * b],
                   axis=1)
    det = a * cof[:, 0] + b * cof[:, 1] + c * cof[:, 2]
    trace = np.maximum(a + d + f, 1e-300)
    ok = det > (MIN_SPREAD * trace) * (trace / 3.0) ** 2
    full = cof[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
    return np.where(ok[:, None, None], full / np.where(ok, det, 1.0)[:, None, None], 0.0), ok


def unique_pairs(a, b):
    """The distinct pairs (a[i], b[i]) of two non-negative integer arrays, sorted by a then b."""
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    base = int(b.max(initial=0)) + 1
    key = distinct(a * base + b)
    return key // base, key % base


class PatchField:
    """The vertices of the elements of ``table``'s front patches (triangles, sub-triangles,
    cells: a clustered patch has many) and the fit of patch values to them."""

    def __init__(self, table):
        el = table.elements_np
        kind, tri = el["kind"], el["triangle"]
        self.elements, self.count = len(kind), table.front_count
        mesh = kind == 0
        corners = np.concatenate([tri, tri[:, :1]], axis=1)
        corners[el["cells"]] = _analytic_corners(kind, el["cells"], el["bounds"], el["frame"])
        self.corner_count = np.where(mesh, 3, 4)
        self.kind, self.element_patch, self.element_normals = kind, el["patch"], el["normal"]
        self.element_shape, self.leaf = el["shape"], el["leaf"]
        self.normals = table.normals_np[:self.count]
        self.areas = table.areas_np[:self.count]
        leaf = el["leaf"]                      # (split elements are not shown: their children are)
        weight = np.where(leaf, el["area"], 0.0)[:, None]    # patch centroids: area-weighted element centres
        on = np.where(leaf, self.element_patch, 0)
        self.centroids = np.stack([np.bincount(on, (weight * el["centre"])[:, k], minlength=self.count)
                                   for k in range(3)], axis=1) / np.maximum(self.areas, 1e-300)[:, None]
        used = (np.arange(4)[None, :] < self.corner_count[:, None]) & leaf[:, None]
        element_of = np.repeat(np.arange(self.elements), 4).reshape(-1, 4)[used]
        points = corners[used]
        del corners
        extent = np.ptp(points, axis=0).max() if len(points) else 1.0
        ids, lead = weld(points, self.element_normals[element_of], extent)
        ids = separate(table.scene, ids, el["centre"][element_of], self.element_normals[element_of], extent, lead)
        mouth = mouth_patches(table)[self.element_patch[element_of]]      # (a gap's mouth: vertices of its own)
        if mouth.any():
            ids = np.unique(ids * 2 + mouth, return_inverse=True)[1].ravel()
        self.vertex_ids = np.zeros((self.elements, 4), np.int64)
        self.vertex_ids[used] = ids
        self.vertex_count = int(ids.max()) + 1 if len(ids) else 0
        self.vertex_positions = np.zeros((self.vertex_count, 3))
        self.vertex_positions[ids] = points          # welded corners coincide
        self._element_incidence = (element_of, ids)
        self._prepare_fit()
        patch, vertex = self._patch_pairs(element_of, ids)
        self._limits = limiter.limits(patch, vertex, limiter.surrounded(
            self.vertex_positions, self.centroids, self.normals, patch, vertex, _tangents))
        # the average over each patch of the interpolated field, a weighted sum of its corners'
        # values: (patch, vertex, weight) per corner, and each vertex's total weight
        corner_patch, corner_weight = self.element_patch[element_of], el["area"][element_of] \
            / self.corner_count[element_of] / np.maximum(self.areas[self.element_patch[element_of]], 1e-300)
        self._averages = (corner_patch, ids, corner_weight,
                          np.bincount(ids, corner_weight, minlength=self.vertex_count))
        del self._element_incidence            # (only the fit reads it: 16 bytes per corner)
        self.vertex_ids = self.vertex_ids.astype(np.uint32)
        self._jit = None

    # ------------------------------------------------------------------ fitting (numpy)
    def _patch_pairs(self, element, vertex):
        """The distinct (patch, vertex) pairs of (element, vertex) pairs."""
        return unique_pairs(self.element_patch[element], vertex)

    def _prepare_fit(self):
        """Per vertex: the coefficients of its value in the values of the patches around it:
        the least-squares plane through the patches sharing it or, where those do not span
        the plane (a corner), through the patches adjacent to them too. A vertex inside one
        patch (a cluster's inner vertices) takes that patch's plane: fitted once per patch,
        through it and its adjacent patches, evaluated at the vertex."""
        patch, vertex = self._patch_pairs(*self._element_incidence)
        self._inner = (np.zeros(0, np.int64),) * 2 + (np.zeros((0, 2)),)
        self._planes = (np.zeros(0, np.int64),) * 2 + (np.zeros((0, 3)),)
        if not len(patch):
            self._pairs, self.planes = (patch, vertex, np.zeros(0)), np.zeros(0, bool)
            return
        inner = np.bincount(vertex, minlength=self.vertex_count)[vertex] == 1
        if inner.any():
            self._patch_planes(patch[inner], vertex[inner])
            patch, vertex = patch[~inner], vertex[~inner]
        coef, plane = self._plane_fit(patch, vertex)
        plane[self._inner[0]] = True
        weak = np.flatnonzero(~plane)
        if len(weak):
            wide_patch, wide_vertex = self._second_ring(patch, vertex, weak)
            wide_coef, wide_plane = self._plane_fit(wide_patch, wide_vertex)
            use = wide_plane[wide_vertex]
            keep = ~np.isin(vertex, weak[wide_plane[weak]])
            patch, vertex, coef = (np.concatenate([a[keep], b[use]]) for a, b in
                                   ((patch, wide_patch), (vertex, wide_vertex), (coef, wide_coef)))
            plane[weak] = wide_plane[weak]
        self._pairs = (patch, vertex, coef)
        self.planes = plane           # per vertex: a plane was fitted (else the mean)

    def _adjacency(self, needed):
        """(a, b) pairs, sorted by a, of each patch of ``needed`` (bool per patch) and every
        patch sharing a vertex with it (itself included)."""
        patch, vertex = self._patch_pairs(*self._element_incidence)
        touching = np.zeros(self.vertex_count, bool)
        touching[vertex[needed[patch]]] = True
        keep = touching[vertex]
        order = np.argsort(vertex[keep], kind="stable")
        by_vertex, sorted_vertex = patch[keep][order], vertex[keep][order]
        start = np.searchsorted(sorted_vertex, np.arange(self.vertex_count + 1))
        size = (start[1:] - start[:-1])[sorted_vertex]
        rep = np.repeat(np.arange(len(by_vertex)), size)
        within = np.arange(len(rep)) - np.repeat(np.cumsum(size) - size, size)
        a, b = unique_pairs(by_vertex[rep], by_vertex[np.repeat(start[sorted_vertex], size) + within])
        mine = needed[a]
        return a[mine], b[mine]

    def _patch_planes(self, patch, vertex):
        """The planes of the patches holding inner vertices (``patch``, ``vertex``: each
        inner vertex and its one patch): per (patch, neighbour) pair the coefficients of the
        plane's value and gradient in the neighbour's value, and the vertices' coordinates."""
        needed = np.zeros(self.count, bool)
        needed[patch] = True
        centre, other = self._adjacency(needed)
        t1, t2 = _tangents(self.normals[centre])
        offset = self.centroids[other] - self.centroids[centre]
        x, y = np.einsum("ij,ij->i", offset, t1), np.einsum("ij,ij->i", offset, t2)
        weight = self.areas[other]
        k = self.count
        total = np.bincount(centre, weight, minlength=k)
        scale = np.sqrt(np.maximum(np.bincount(centre, weight * (x * x + y * y), minlength=k)
                                   / np.maximum(total, 1e-300), 1e-300))
        rows = np.stack([np.ones(len(centre)), x / scale[centre], y / scale[centre]], axis=1)
        inverse, ok = _inverses(np.stack([np.bincount(centre, weight * rows[:, i] * rows[:, j], minlength=k)
                                          for i, j in _UPPER], axis=1))
        coef = np.einsum("pij,pj->pi", inverse[centre], rows) * weight[:, None]
        # a patch whose neighbours do not span a plane: its own value, flat
        flat = ~ok[centre]
        coef[flat] = np.where((other == centre)[flat][:, None], [[1.0, 0.0, 0.0]], 0.0)
        self._planes = (centre, other, coef)
        pt1, pt2 = _tangents(self.normals[patch])
        local = self.vertex_positions[vertex] - self.centroids[patch]
        self._inner = (vertex, patch, np.stack([np.einsum("ij,ij->i", local, pt1),
                                                np.einsum("ij,ij->i", local, pt2)], axis=1) / scale[patch][:, None])

    def _second_ring(self, patch, vertex, weak):
        """(patch, vertex) pairs for the vertices ``weak``: their patches and every patch
        adjacent to one of those."""
        first = np.isin(vertex, weak)
        needed = np.zeros(self.count, bool)
        needed[patch[first]] = True
        adjacent = np.stack(self._adjacency(needed), axis=1)
        a_start = np.searchsorted(adjacent[:, 0], np.arange(self.count + 1))
        v1, p1 = vertex[first], patch[first]
        n = a_start[p1 + 1] - a_start[p1]
        index = np.repeat(a_start[p1], n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        return unique_pairs(adjacent[index, 1], np.repeat(v1, n))

    def _sum(self, vertex, values):
        """Per vertex, the sum of ``values`` (N,) or (N, k) over the pairs of ``vertex``."""
        v = self.vertex_count
        if values.ndim == 1:
            return np.bincount(vertex, values, minlength=v)
        return np.stack([np.bincount(vertex, values[:, k], minlength=v) for k in range(values.shape[1])], axis=1)

    def _plane_fit(self, patch, vertex):
        """(coefficient per pair, plane per vertex) of the area-weighted least-squares plane
        at each vertex through the centroid values of its ``patch`` pairs (the mean where the
        centroids do not span the plane)."""
        weight = self.areas[patch]
        t1, t2 = _tangents(self._sum(vertex, self.normals[patch] * weight[:, None]))
        offset = self.centroids[patch] - self.vertex_positions[vertex]
        x, y = np.einsum("ij,ij->i", offset, t1[vertex]), np.einsum("ij,ij->i", offset, t2[vertex])
        total = self._sum(vertex, weight)
        scale = np.sqrt(np.maximum(self._sum(vertex, weight * (x * x + y * y)) / np.maximum(total, 1e-300),
                                   1e-300))[vertex]      # one length per vertex: a plane in (x, y)
        rows = np.stack([np.ones(len(patch)), x / scale, y / scale], axis=1)
        inverse, plane = _inverses(self._sum(vertex, weight[:, None] * (rows[:, [0, 0, 0, 1, 1, 2]]
                                                                      * rows[:, [0, 1, 2, 1, 2, 2]])))
        # the plane's value at the vertex is a linear combination of the patch values
        coef = np.einsum("pj,pj->p", inverse[vertex][:, 0, :], rows) * weight
        mean = weight / np.maximum(total[vertex], 1e-300)
        return np.where(plane[vertex], coef, mean), plane

    def fit(self, values, iterations=CONSERVE_ITERATIONS):
        """Vertex values (V, C) from patch values (K, C) (or (K, ...): trailing axes are
        channels): the planes, then ``iterations`` corrections (:meth:`conserve`), each
        after the limiter (:mod:`mi_plugins.solution.limiter`)."""
        values = np.asarray(values, dtype=np.float64)
        shape = values.shape[1:]
        flat = values.reshape(self.count, -1)
        patch, vertex, coef = self._pairs
        out = np.zeros((self.vertex_count, flat.shape[1]))
        for c in range(flat.shape[1]):
            out[:, c] = np.bincount(vertex, coef * flat[patch, c], minlength=self.vertex_count)
        centre, other, plane = self._planes
        if len(centre):            # inner vertices: their patch's plane
            inner, at, local = self._inner
            for c in range(flat.shape[1]):    # (the channels: a few)
                beta = [np.bincount(centre, plane[:, j] * flat[other, c], minlength=self.count) for j in range(3)]
                out[inner, c] = beta[0][at] + local[:, 0] * beta[1][at] + local[:, 1] * beta[2][at]
        for _ in range(int(iterations)):       # (the limiter before each correction)
            out = self.conserve(limiter.limited(out, flat, self._limits), flat, 1)
        return out.reshape((self.vertex_count,) + shape)

    def conserve(self, out, flat, iterations=CONSERVE_ITERATIONS):
        """Vertex values ``out`` (V, C) moved toward patch averages equal to the patch
        values ``flat`` (K, C): ``iterations`` steps, each adding to every vertex the
        weighted mean residual of the patches around it (see the module docstring)."""
        patch, vertex, weight, total = self._averages
        for _ in range(int(iterations)):
            for c in range(flat.shape[1]):
                residual = flat[:, c] - np.bincount(patch, weight * out[vertex, c], minlength=self.count)
                out[:, c] += np.bincount(vertex, weight * residual[patch], minlength=self.vertex_count) \
                    / np.maximum(total, 1e-300)
        return out

    # ------------------------------------------------------------------ the setup cache
    def arrays(self):
        """{name: numpy array} of the field (:mod:`mi_plugins.patches.setup_cache`)."""
        return setup_cache.pack({k: v for k, v in self.__dict__.items() if k != "_jit"})

    @classmethod
    def from_arrays(cls, arrays, order=None):
        """The field stored by :meth:`arrays`, its patches, elements and shapes renumbered
        by ``order`` (:class:`mi_plugins.patches.setup_cache.ShapeOrder`; None: as stored);
        its vertices keep their stored numbers (any numbering is one)."""
        field = cls.__new__(cls)
        field.__dict__.update(setup_cache.unpack(arrays))
        field._jit = None
        if order is not None:
            field._renumber(order)
        return field

    #: the field's arrays by what their rows are (elements, patches) and what values
    #: name a patch: (attribute, index in its tuple or None)
    _BY_ELEMENT = ("corner_count", "kind", "element_patch", "element_normals", "element_shape", "leaf", "vertex_ids")
    _BY_PATCH = ("normals", "areas", "centroids")
    _PATCH_VALUES = (("element_patch", None), ("_pairs", 0), ("_planes", 0), ("_planes", 1), ("_inner", 1),
                     ("_averages", 0), ("_limits", 0))

    def _renumber(self, order):
        for name in self._BY_ELEMENT:
            setattr(self, name, getattr(self, name)[order.element])
        for name in self._BY_PATCH:
            setattr(self, name, getattr(self, name)[order.patch])
        for name, k in self._PATCH_VALUES:
            value = getattr(self, name)
            if k is None:
                setattr(self, name, np.where(value >= 0, order.patches(np.maximum(value, 0)), value))
            else:
                setattr(self, name, value[:k] + (order.patches(value[k]),) + value[k + 1:])
        self.element_shape = order.shape[self.element_shape]

    # ------------------------------------------------------------------ kernels
    def jit(self):
        """The arrays kernels read (made once)."""
        if self._jit is None:
            ids = np.concatenate([self.vertex_ids, np.zeros((2, 4), np.uint32)])  # (never width 1)
            self._jit = [jit(mi.UInt32, ids[:, j]) for j in range(4)]
        return self._jit

    def weights(self, element, mesh, a, b, active=True):
        """Per lane: the four vertex indices (UInt32) and weights (Float) of points of
        elements ``element`` at coordinates (a, b) (``MeshTable.locate``: barycentric on
        triangles, bilinear on cells)."""
        ids = [dr.gather(mi.UInt32, arr, element, active) for arr in self.jit()]
        w = [dr.select(mesh, 1.0 - a - b, (1.0 - a) * (1.0 - b)), dr.select(mesh, a, a * (1.0 - b)),
             dr.select(mesh, b, (1.0 - a) * b), dr.select(mesh, 0.0, a * b)]
        return ids, w


def field_of(table):
    """The :class:`PatchField` of ``table``, made once per table and kept with it
    (``MeshTable.derived``): it depends on the patches' geometry only, not on a solution,
    so every solve and every loaded solution on the same table shares it (on a million
    triangles it takes seconds, more than the solve of a 1 s budget)."""
    return table.derived("patch field", lambda: PatchField(table), (PatchField.arrays, PatchField.from_arrays))
