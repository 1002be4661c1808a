"""Vertex normals that contradict a mesh's winding.

The finite-element integrators (``ray_bundle``, ``qmc_lighttrace``) store light per patch
*side*: the side the geometric normal points to (the winding of the triangle, negated by
``flip_normals``) or the other one. Mitsuba's BSDFs, and ``path``, decide a side by the
*shading* normal, interpolated from the vertex normals. Where the two point to opposite
sides, light stored on one side is read by Mitsuba on the other, and the image differs
from ``path`` (an arrival whose sides differ is not stored, a view whose sides differ
reads nothing: ``qmc_surfaces``).

At grazing angles this touches a sliver of every smooth-shaded mesh (documented as a bias
of the displays). But a mesh with inconsistent winding (some triangles listed clockwise,
as scanned and converted meshes often are) whose vertex normals Mitsuba averaged from the
faces has whole regions where the interpolated normal points to the other side of the
triangle. Measured on a closed box whose triangles were 30 % flipped, ``twosided``
diffuse: the patches display 20 % dark, the gathered ``qmc_lighttrace`` image 8 % dark,
silently. The same holds everywhere on a mesh mirrored by its ``to_world`` (a negative
scale) whose normals come from its file: Mitsuba reverses the winding's normal, not the
file's normals (100 % of the area). Such meshes are refused: :func:`require_consistent_normals`.
"""
import mitsuba as mi
import numpy as np

from mi_plugins.base.errors import Unsupported

#: a mesh is refused when the interpolated vertex normal points to the other side of its
#: triangle on more than this share of its area
MAX_CONFLICT = 0.002


def conflict_share(verts, faces, normals):
    """The share of the area of the triangles ``faces`` (F, 3) of ``verts`` (V, 3) on
    which the vertex ``normals`` (V, 3), interpolated with the barycentrics as Mitsuba
    does, point to the other side of the triangle's winding normal.

    Along a triangle the sign of dot(interpolated normal, winding normal) is the sign of
    a function linear in the barycentrics, sum_i b_i d_i with d_i the corner's dot (the
    normalisation does not change signs): the region where it is negative is the whole
    triangle, none of it, or the part cut off by one straight line, whose area share
    follows from where the line crosses the edges."""
    p = verts[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    total = float(area.sum())
    if not len(faces) or total <= 0:
        return 0.0
    d = np.einsum("tkj,tj->tk", normals[faces], cross)
    negative = d < 0
    count = negative.sum(axis=1)
    share = (count == 3).astype(np.float64)
    for odd, value in ((1, True), (2, False)):      # the one corner on its own side of the line
        rows = np.flatnonzero(count == odd)
        if not len(rows):
            continue
        dd = d[rows]
        alone = np.argmax(negative[rows] == value, axis=1)
        k = np.arange(len(rows))
        a, b, c = dd[k, alone], dd[k, (alone + 1) % 3], dd[k, (alone + 2) % 3]
        corner = (a / (a - b)) * (a / (a - c))        # the corner's triangle, cut off by the line
        share[rows] = corner if value else 1.0 - corner
    return float((share * area).sum() / total)


def require_consistent_normals(shape, verts, faces, who):
    """Raise :class:`mi_plugins.base.errors.Unsupported` if ``shape`` (a mesh whose vertex
    positions and faces are ``verts``, ``faces``) has vertex normals whose interpolated
    normal points to the other side of its triangles on more than :data:`MAX_CONFLICT`
    of its area."""
    if not shape.has_vertex_normals():
        return
    normals = np.array(mi.traverse(shape)["vertex_normals"], dtype=np.float64).reshape(-1, 3)
    share = conflict_share(verts, faces, normals)
    if share > MAX_CONFLICT:
        raise Unsupported(
            who, "vertex normals", "shape '%s' with its vertex normals" % shape.id(),
            "on %.3g %% of its area the interpolated normal points to the other side of the triangle than its "
            "winding (at most %g %%: the mark of a mesh with inconsistent winding whose normals were averaged "
            "from its faces); the patches store light by the winding's side and Mitsuba's BSDFs read it by the "
            "normal's side, so the image would be wrong" % (100 * share, 100 * MAX_CONFLICT),
            "give the shape face_normals=true, or make its winding consistent, or render it with path")
