"""The smooth field averaged over the children of the patches: what the smooth display
shows in each part of a patch that adaptive subdivision would make
(``mi_plugins.patches.refinement``), to compare with what those parts received."""
import numpy as np

from mi_plugins.patches.refinement import CHILDREN, element_octants
from mi_plugins.solution.patchfield import field_of

#: the centroids (b1, b2) of a triangle's level-2 sub-triangles (children 0 .. 3), where a
#: field linear over the triangle takes its average over each
_SUB_CENTROIDS = np.array([[1 / 6, 1 / 6], [1 / 3, 1 / 3], [2 / 3, 1 / 6], [1 / 6, 2 / 3]])
#: the centres (a, b) of a cell's uv quadrants (children 0 .. 3), where a bilinear field
#: takes its average over each
_QUADRANT_CENTRES = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]])


def field_children(table, density):
    """(K, S, 8) numpy: the smooth field (:mod:`mi_plugins.solution.patchfield`) fitted to
    the patch sides' ``density`` (K, S), averaged over each child of each patch: what the
    smooth display shows there. 0 where a child is absent."""
    field = field_of(table)
    k, sides = density.shape
    vertex = field.fit(density)                                    # (V, S)
    el = table.elements_np
    leaf, patch = el["leaf"], el["patch"]
    corners = vertex[field.vertex_ids.astype(np.int64)]             # (E, 4, S)
    out = np.zeros((k, sides, CHILDREN))
    counts = np.bincount(patch[leaf], minlength=k)
    many = leaf & (counts[np.maximum(patch, 0)] > 1)
    mesh = el["kind"] == 0
    # a cluster's octant: the area-weighted mean of its elements' averages (a triangle's is
    # the mean of its 3 corners, a cell's of its 4)
    average = np.where(mesh[:, None], corners[:, :3].mean(axis=1), corners.mean(axis=1))
    weight = np.zeros((k, CHILDREN))
    octant = element_octants(table).astype(np.int64)
    np.add.at(weight, (patch[many], octant[many]), el["area"][many])
    for c in range(sides):
        np.add.at(out[:, c], (patch[many], octant[many]), el["area"][many] * average[many, c])
    out /= np.maximum(weight, 1e-300)[:, None, :]
    one = leaf & ~many
    for kind, points, corner_weights in (
            (mesh, _SUB_CENTROIDS, lambda a, b: [1 - a - b, a, b, 0 * a]),
            (~mesh, _QUADRANT_CENTRES, lambda a, b: [(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b])):
        chosen = np.flatnonzero(one & kind)
        for child, (a, b) in enumerate(points):
            w = np.array(corner_weights(a, b))
            out[patch[chosen], :, child] = np.einsum("j,ejs->es", w, corners[chosen])
    return out
