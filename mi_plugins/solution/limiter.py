"""The smooth field's limiter: a vertex that its patches surround is kept within their
values before each correction of the field.

A vertex value of :class:`mi_plugins.solution.patchfield.PatchField` is a least-squares
plane through the values of the patches around it, evaluated at the vertex, then moved
toward the patch averages. Beside a steep change (a lit strip on a shadowed floor) the
plane fitted across the change overshoots: the floor beside the strip far too bright.

Where the vertex lies inside the convex hull of its patches' centroids (in the plane of
its surface), a field linear in position takes there a value between the patches' own
values; the limiter keeps the vertex within the smallest and largest of them. A vertex
outside that hull (on a border, at a corner: the plane is extrapolated there) may leave
its patches' range, as a linear field does there, but not fall below zero where they are
all at or above it (a field nowhere negative on the surface is not negative at its
vertices). A linear field without negative values is untouched.

The limiter acts before each correction toward the patch averages, not after the last:
the corrections then take back what it moved where the patches' light is noisy and
heavy-tailed (a caustic, whose overshoot below its edge balances the one above it; a
limit after the last correction read the conformance suite's ``mirror_lit`` +2.2 %, z
+7.6, as a clamp at 0 had read it +4 %), and what stays cut is the gross overshoot beside
a steep change. The corrections can still take a vertex beside such a change below zero.
"""
import numpy as np

#: a vertex is surrounded when no gap between the directions to its patches' centroids,
#: seen from it in its surface's plane, reaches half a turn less this margin (radians)
MARGIN = 1e-6


def surrounded(positions, centroids, normals, patch, vertex, tangents):
    """Bool per vertex (len(``positions``)): the centroids of the patches ``patch`` around
    each vertex ``vertex`` (pairs) surround it in the tangent plane of the patches' mean
    normal ``normals`` (per patch): every gap between consecutive directions to them is
    under half a turn. ``tangents(normals)``: two unit tangents per normal."""
    count = len(positions)
    counts = np.bincount(vertex, minlength=count)
    keep = counts[vertex] >= 3                  # (fewer than 3 patches surround nothing)
    patch, vertex = patch[keep], vertex[keep]
    out = np.zeros(count, bool)
    if not len(vertex):
        return out
    mean = np.stack([np.bincount(vertex, normals[patch][:, k], minlength=count) for k in range(3)], axis=1)
    t1, t2 = tangents(mean)
    offset = centroids[patch] - positions[vertex]
    angle = np.arctan2(np.einsum("ij,ij->i", offset, t2[vertex]), np.einsum("ij,ij->i", offset, t1[vertex]))
    # by vertex, then by angle: one sort of the vertex plus the angle's share of a turn
    order = np.argsort(vertex + (angle + np.pi) / (2.0 * np.pi + 1e-9), kind="stable")
    v, a = vertex[order], angle[order]
    starts = np.flatnonzero(np.r_[True, v[1:] != v[:-1]])
    ends = np.r_[starts[1:], len(v)] - 1
    gap = np.empty(len(a))
    gap[:-1] = a[1:] - a[:-1]
    # the gap after a vertex's last direction wraps to its first
    gap[ends] = a[starts] + 2.0 * np.pi - a[ends]
    out[v[starts]] = np.maximum.reduceat(gap, starts) < np.pi - MARGIN
    return out


def limits(patch, vertex, inside):
    """(patches, group starts, group vertices, group surrounded): the pairs (``patch``,
    ``vertex``) grouped by vertex, and whether each group's vertex is ``inside``, which
    :func:`limited` reads."""
    order = np.argsort(vertex, kind="stable")
    p, v = patch[order], vertex[order]
    starts = np.flatnonzero(np.r_[True, v[1:] != v[:-1]]) if len(v) else np.zeros(0, np.int64)
    return p, starts, v[starts], inside[v[starts]]


def limited(out, flat, groups):
    """Vertex values ``out`` (V, C) limited (see the module docstring): a vertex its
    patches surround within the smallest and largest of their values ``flat`` (K, C), any
    other vertex not below 0 where none of them is."""
    p, starts, v, inside = groups
    if not len(v):
        return out
    for c in range(out.shape[1]):             # (the channels: a few)
        values = flat[p, c]
        lo, hi = np.minimum.reduceat(values, starts), np.maximum.reduceat(values, starts)
        floor = np.where(lo >= 0.0, 0.0, -np.inf)       # (a vertex not surrounded)
        out[v, c] = np.clip(out[v, c], np.where(inside, lo, floor), np.where(inside, hi, np.inf))
    return out
