"""The patches of one shape for :class:`mi_plugins.patches.meshtable.MeshTable`: its *elements*
(triangles and cells, the pieces a hit is found in) and how they group into patches.

A mesh triangle longer than the patch size h is split into s x s similar sub-triangles,
each its own patch (s the smallest level whose sub-triangles have edges <= sqrt(2) h, at
most :data:`MAX_SPLIT`). Triangles much smaller than h (longest edge below
:data:`CLUSTER_BELOW` h) are *clustered*: grouped by the cell of a grid of spacing h
holding their centroid and by the direction of their normal (:func:`normal_bucket`:
within about 45 degrees), one patch per group, so that the patch count follows the
surface area and h rather than the triangle count (a scanned mesh of a million triangles
has as many patches as the same surface modelled with a few). A hit finds its element
(parent triangle and sub-triangle) and its patch through one table lookup. An analytic
shape's cells (``mi_plugins.patches.tessellation``) are one element and one patch each.
"""
import numpy as np

from mi_plugins.base.arrays import distinct, row_keys
from mi_plugins.patches import tessellation

#: subdivision level s (s x s sub-triangles per triangle) at the most
MAX_SPLIT = 64
#: triangles whose longest edge is below this share of the patch size are clustered
CLUSTER_BELOW = 0.5
#: cells of the cube map of normal directions per face side (normals of one cluster are
#: within about 90 / CUBE_CELLS degrees of each other in each direction)
CUBE_CELLS = 2


def split_levels(p, h):
    """Subdivision level per triangle (corners ``p``, (n, 3, 3)): the smallest s with
    longest edge / s <= sqrt(2) h, at most MAX_SPLIT; 1 everywhere when ``h`` is None."""
    if h is None or not len(p):
        return np.ones(len(p), dtype=np.int64)
    edge = longest_edges(p)
    return np.clip(np.ceil(edge / (np.sqrt(2.0) * h) * (1 - 1e-9)), 1, MAX_SPLIT).astype(np.int64)


def longest_edges(p):
    """The longest edge of each triangle of corners ``p`` (n, 3, 3)."""
    d = p - p[:, [2, 0, 1]]
    return np.sqrt(np.einsum("nkc,nkc->nk", d, d).max(axis=1))


def sub_triangles(s):
    """Barycentric corners (b1, b2) of the s x s sub-triangles, (s^2, 3, 2), in the order
    of :func:`mi_plugins.patches.tessellation.sub_triangle_coords`
    (:func:`mi_plugins.patches.tessellation.triangle_lattice`)."""
    return tessellation.triangle_lattice(s) / float(s)


def normal_bucket(normals):
    """An integer per unit normal: its cube-map face (6) and a CUBE_CELLS x CUBE_CELLS cell
    of it (normals of one bucket are within about 45 degrees of each other)."""
    axis = np.argmax(np.abs(normals), axis=1)
    n = len(normals)
    major = normals[np.arange(n), axis]
    face = axis * 2 + (major < 0)
    others = np.stack([normals[np.arange(n), (axis + 1) % 3], normals[np.arange(n), (axis + 2) % 3]], axis=1)
    cells = np.clip(np.floor((others / np.maximum(np.abs(major), 1e-30)[:, None] + 1) * 0.5 * CUBE_CELLS), 0,
                    CUBE_CELLS - 1).astype(np.int64)
    return (face * CUBE_CELLS + cells[:, 0]) * CUBE_CELLS + cells[:, 1]


def cluster_triangles(p, normals, h):
    """Local patch index per triangle (corners ``p`` (n, 3, 3), unit ``normals``): the
    small ones grouped by grid cell of ``h`` and normal bucket, the others alone; patches
    numbered by their first triangle (None: no triangle is small)."""
    small = longest_edges(p) < CLUSTER_BELOW * h
    if not small.any():
        return None
    cell = np.floor(p.mean(axis=1) / h).astype(np.int64)
    keys = np.concatenate([cell, normal_bucket(normals)[:, None]], axis=1)
    keys[~small] = np.stack([np.full((~small).sum(), np.iinfo(np.int64).min), np.flatnonzero(~small),
                             np.zeros((~small).sum(), np.int64), np.zeros((~small).sum(), np.int64)], axis=1)
    packed = row_keys(keys)
    _, first, group = (np.unique(packed, return_index=True, return_inverse=True) if packed is not None
                       else np.unique(keys, axis=0, return_index=True, return_inverse=True))
    order = np.argsort(np.argsort(first))          # groups numbered by their first triangle
    return order[group.ravel()]


def patch_count(p, h, subdivide=True, cluster=True):
    """The patches of a mesh with triangle corners ``p`` (n, 3, 3), as :func:`mesh_part`
    makes them, without making them."""
    if not len(p):
        return 0
    level = split_levels(p, h if subdivide else None)
    if not cluster or h is None:
        return int(np.sum(level ** 2))
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    groups = cluster_triangles(p, cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-30), h)
    if groups is None:
        return int(np.sum(level ** 2))
    return int(np.sum(level[level > 1] ** 2)) + len(distinct(groups[level == 1]))


def _runs(level):
    """(value, run length) of consecutive equal entries of ``level``."""
    if not len(level):
        return []
    cut = np.flatnonzero(np.diff(level)) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [len(level)]])
    return [(int(level[a]), int(b - a)) for a, b in zip(starts, ends)]


def mesh_part(verts, faces, uv, flipped, h, subdivide=True, cluster=True):
    """The elements of a mesh (vertices (V, 3), faces (F, 3), per-face uv (F, 3, 2) or
    None, ``flip_normals``): its triangles split where long (``subdivide``) and grouped
    where small (``cluster``); returns a dict of per-element and per-parent arrays."""
    p = verts[faces]
    if uv is None:
        uv = np.tile(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), (len(faces), 1, 1))
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    if flipped:                  # Mitsuba's orientation: flip_normals negates the winding's
        cross = -cross
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(2 * area[:, None], 1e-30)
    level = split_levels(p, h if subdivide else None)
    count = level * level
    parent = np.repeat(np.arange(len(faces)), count)
    bary = np.concatenate([sub_triangles(s)[None].repeat(n, 0).reshape(-1, 3, 2)
                           for s, n in _runs(level)]) if len(faces) else np.zeros((0, 3, 2))
    weights = np.stack([1 - bary[..., 0] - bary[..., 1], bary[..., 0], bary[..., 1]], axis=-1)   # (n, 3, 3)
    tri = np.einsum("nkc,ncd->nkd", weights, p[parent])
    tuv = np.einsum("nkc,ncd->nkd", weights, uv[parent])
    n = len(parent)
    groups = cluster_triangles(p, normal, h) if cluster and h is not None and len(faces) else None
    # a clustered triangle is small, hence not split: one element per parent there
    elem_patch = np.arange(n) if groups is None else _relabel(groups[parent], level)
    corner = np.zeros(len(verts), bool)          # the hull's points: the vertices faces use (once each)
    corner[faces.ravel()] = True
    return with_hierarchy(dict(kind=np.zeros(n, np.uint32), prim=parent.astype(np.uint32), nu=0, nv=0,
                               area=(area / count)[parent], normal=normal[parent], triangle=tri, uv=tuv,
                               bounds=np.zeros((n, 4)), frame=np.zeros((n, 21)), points=verts[corner], parents=p,
                               level=level, first=np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64),
                               patch=elem_patch))


def _relabel(groups, level):
    """Patch per element: the parents' groups, split parents' sub-triangles their own
    patches (a split parent is never clustered: it is long), numbered in element order."""
    labels = np.where(np.repeat(level, level * level) > 1, -1 - np.arange(len(groups)), groups)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    return np.argsort(np.argsort(first))[inverse.ravel()]


def analytic_part(shape, h):
    """The cells of an analytic shape: one element and one patch each."""
    cells = tessellation.ShapePatches(shape, h)
    n = cells.count
    box = shape.bbox()
    lo, hi = np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)
    corners = np.array([[(hi if k >> j & 1 else lo)[j] for j in range(3)] for k in range(8)])
    return with_hierarchy(dict(kind=np.full(n, cells.kind, np.uint32), prim=np.zeros(n, np.uint32), nu=cells.nu,
                               nv=cells.nv, area=cells.areas, normal=cells.normals, triangle=np.zeros((n, 3, 3)),
                               uv=np.zeros((n, 3, 2)), bounds=cells.bounds, frame=np.tile(cells.frame.columns, (n, 1)),
                               points=corners, patch=np.arange(n), centre=cells.centres,
                               surface_area=cells.surface_area))


# ---------------------------------------------------------------------------- refinement
#: the most times an element is split (each split: 4 children)
MAX_DEPTH = 6


def leaves(part):
    """Bool per element: a leaf (not split)."""
    return part["child"] < 0


def refine(part, split, h):
    """A copy of ``part`` with the patches ``split`` (local patch indices) split in two to
    four: a patch of one element (a triangle, a sub-triangle, a cell) into the element's
    4 children (the level-2 sub-triangles of :func:`sub_triangles`, the uv quadrants of a
    cell), appended as elements of their own; a cluster into the octants of its grid
    cell (``h``: the part's patch size). Children take patch numbers after the part's
    others; ``parent`` maps every element to the one it was split from (-1)."""
    part = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in part.items()}
    patch, leaf = part["patch"], leaves(part)
    elements_of = np.bincount(patch[leaf], minlength=int(patch.max()) + 1)
    split = distinct(np.asarray(split, np.int64))
    single = split[elements_of[split] == 1]
    clusters = split[elements_of[split] > 1]
    grow = np.flatnonzero(leaf & np.isin(patch, single) & (part["depth"] < MAX_DEPTH))
    next_patch = int(patch.max()) + 1
    if len(clusters):
        members = np.flatnonzero(leaf & np.isin(patch, clusters))
        cell = h / 2.0 ** (part["depth"][members] + 1)
        octant = np.floor(part["centre"][members] / cell[:, None]).astype(np.int64) % 2
        key = patch[members] * 8 + octant[:, 0] * 4 + octant[:, 1] * 2 + octant[:, 2]
        _, group = np.unique(key, return_inverse=True)
        patch[members] = next_patch + group.ravel()
        part["depth"][members] += 1
        next_patch = int(patch.max()) + 1
    if len(grow):
        part = _split_elements(part, grow, next_patch)
    part["patch"] = _renumber(part["patch"], leaves(part))
    return part


def _split_elements(part, grow, next_patch):
    """Append the 4 children of each element of ``grow`` (numbered from ``next_patch``)."""
    n, k = len(part["area"]), len(grow)
    mesh = part["kind"][grow] == 0
    w = sub_triangles(2)                                       # (4, 3, 2) corner weights
    weights = np.stack([1 - w[..., 0] - w[..., 1], w[..., 0], w[..., 1]], axis=-1)   # (4, 3, 3)
    tri = np.einsum("jkc,ncd->njkd", weights, part["triangle"][grow]).reshape(-1, 3, 3)
    uv = np.einsum("jkc,ncd->njkd", weights, part["uv"][grow]).reshape(-1, 3, 2)
    u0, u1, v0, v1 = part["bounds"][grow].T
    um, vm = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    bounds = np.stack([np.stack(b, axis=1) for b in ((u0, um, v0, vm), (um, u1, v0, vm), (u0, um, vm, v1),
                                                    (um, u1, vm, v1))], axis=1).reshape(-1, 4)
    rep = lambda a: np.repeat(a, 4, axis=0)
    kind = rep(part["kind"][grow])
    area = np.where(rep(mesh), rep(part["area"][grow]) / 4.0,
                    tessellation.area_share(int(kind[0]) if (~mesh).any() else 1, bounds)
                    * part.get("surface_area", 0.0))
    centre, normal, frame = tri.mean(axis=1), rep(part["normal"][grow]), rep(part["frame"][grow])
    cells = ~rep(mesh)
    if cells.any():          # an analytic cell's children: their own centres and normals
        centre[cells], normal[cells] = tessellation.cell_centres(int(kind[cells][0]), bounds[cells], frame[cells])
    out = dict(part)
    for key, value in (("kind", kind), ("prim", rep(part["prim"][grow])), ("area", area),
                       ("normal", normal), ("triangle", tri), ("uv", uv), ("bounds", bounds),
                       ("frame", frame), ("centre", centre),
                       ("depth", rep(part["depth"][grow]) + 1), ("child", np.full(4 * k, -1, np.int64)),
                       ("parent", rep(grow)), ("patch", next_patch + np.arange(4 * k))):
        out[key] = np.concatenate([part[key], value])
    out["child"][grow] = n + 4 * np.arange(k)
    out["patch"][grow] = -1
    return out


def _renumber(patch, leaf):
    """Patch labels of the leaves renumbered 0 .. P-1 by first appearance; -1 elsewhere."""
    out = np.full(len(patch), -1, np.int64)
    _, first, inverse = np.unique(patch[leaf], return_index=True, return_inverse=True)
    out[leaf] = np.argsort(np.argsort(first))[inverse.ravel()]
    return out


def with_hierarchy(part):
    """``part`` with the fields of refinement: no element split yet."""
    n = len(part["area"])
    part.setdefault("centre", part["triangle"].mean(axis=1))
    part.update(child=np.full(n, -1, np.int64), parent=np.full(n, -1, np.int64), depth=np.zeros(n, np.int64))
    return part
