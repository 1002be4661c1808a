"""Adaptive subdivision: patches split where the light they receive varies, or where the
smooth field shown from them misses how it varies.

A solve measures, for every patch side, what arrives in each of its *children*: the 4
level-2 sub-triangles of a triangle, the 4 uv quadrants of a cell, the up to 8 octants of
a cluster's grid cell (:func:`child_index`: the same children ``MeshTable.refined``
makes). After a stage of the solve, :func:`choose` splits the patches whose children's irradiances
differ from the patch's beyond their noise together (a chi-square test at :data:`Z`
sigma) and some child's by more than ``threshold`` of it (with a display mode: the
children's irradiances differ from the smooth field's averages over them, what the
display shows there, so the budget goes to kinks, shadow edges and contact lines that the
field's planes round off rather than to falloffs they follow): the variation of the incoming
radiance inside the patch, with each child's standard error estimated from its deposits
(the stochastic-iteration paper's remedy:
"much more robust than methods which examine the radiosity gradient"; it finds shadow
boundaries and highlights inside a patch), the largest errors first, down to ``min_size``
and within ``budget`` patches. A uniform field splits nothing: its children agree to
their noise.

:func:`refined` makes the new table and says, for every new patch, which patch and which
child of it it came from, so that a child starts from what its parent measured there.
The rounds of a solve are replayed from ``Solution.meta['refinements']`` (:func:`replay`).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import caches
from mi_plugins.base.param_docs import Row

from mi_plugins.patches.tessellation import sub_triangle_coords
from mi_plugins.patches import tessellation

#: children per patch side (an octant of a cluster's cell; 4 on triangles and cells)
CHILDREN = 8
#: the default patch budget of a refined solution (``max_patches``), times the initial patches
DEFAULT_BUDGET = 4
#: the significance of a patch's variation: the upper tail of a normal beyond this many sigma
Z = 4.0


#: the parameters of adaptive subdivision, read by :func:`read_parameters`
REFINE_ROWS = (
    Row("refine", "bool", "false",
        "adaptive subdivision of a view-independent solution: while it is solved, the patches inside which its "
        "light varies (their children's estimates differ beyond their noise together, at 4 sigma, and a "
        "child's by more than ``refine_threshold``) split, the largest errors first, and the solve goes on on "
        "the refined patches (``mi_plugins.patches.refinement``)"),
    Row("refine_threshold", "float", "0.1", "> 0: the relative variation that splits a patch"),
    Row("min_patch_size", "float", "patch_size / 4", "> 0: patches are not split below this size"),
    Row("max_patches", "int", "4 x the patches before refining", ">= 1: splits stop at this many patches"),
)


def read_parameters(p):
    """(refine, refine_threshold, min_patch_size, max_patches) of an integrator, read with
    its Params ``p`` (:data:`REFINE_ROWS`)."""
    return (p.bool("refine", False), p.float("refine_threshold", 0.1, lo=0, lo_open=True),
            p.float("min_patch_size", None, lo=0, lo_open=True, note="optional: patch_size / 4"),
            p.int("max_patches", None, lo=1, note="optional: 4 x the patches before refining"))


def element_octants(table):
    """numpy per element: the octant (0 .. 7) of its centre in its cluster's grid cell at
    the next depth (the children of a cluster; 0 for elements of single-element patches)."""
    el = table.elements_np
    cell = table.h / 2.0 ** (el["depth"] + 1)
    octant = np.floor(el["centre"] / cell[:, None]).astype(np.int64) % 2
    return (octant[:, 0] * 4 + octant[:, 1] * 2 + octant[:, 2]).astype(np.uint32)


def _jit(table):
    """The arrays :func:`child_index` reads (made once per table)."""
    if getattr(table, "_octant", None) is None:
        table._octant = mi.UInt32(element_octants(table))
    return table._octant


def child_index(table, located, active=True):
    """Per hit (``located``: ``table.locate(si)``), the child 0 .. 7 of its patch holding it."""
    patch, element, mesh, a, b = located
    many = dr.gather(mi.UInt32, table._patch_elements, patch, active) > 1
    sub = sub_triangle_coords(2, a, b)[0]
    quadrant = dr.select(b >= 0.5, 2, 0) + dr.select(a >= 0.5, 1, 0)
    single = dr.select(mesh, sub, quadrant)
    return dr.select(many, dr.gather(mi.UInt32, _jit(table), element, active), single)


def child_areas(table):
    """(K, 8) numpy: the area of every child of every front patch."""
    el = table.elements_np
    k = table.front_count
    leaf = el["leaf"]
    patch = el["patch"]
    out = np.zeros((k, CHILDREN))
    counts = np.bincount(patch[leaf], minlength=k)
    many = counts[np.maximum(patch, 0)] > 1
    cl = leaf & many
    np.add.at(out, (patch[cl], element_octants(table)[cl].astype(np.int64)), el["area"][cl])
    one = leaf & ~many
    mesh = one & (el["kind"] == 0)
    out[patch[mesh], :4] = el["area"][mesh, None] / 4.0
    for part, offset, first in zip(table.parts, table.face_offsets, table.element_offsets):
        cells = np.flatnonzero((part["child"] < 0) & (part["kind"] != 0))
        if not len(cells):
            continue
        u0, u1, v0, v1 = part["bounds"][cells].T
        um, vm = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
        kind = int(part["kind"][cells[0]])
        for c, box in enumerate(((u0, um, v0, vm), (um, u1, v0, vm), (u0, um, vm, v1), (um, u1, vm, v1))):
            out[part["patch"][cells] + int(offset), c] = tessellation.area_share(kind, np.stack(box, axis=1)) \
                * part["surface_area"]
    return out


def patch_sizes(table):
    """numpy (K,): the size of every front patch: its cell's (clusters) or sqrt(2 area)."""
    el = table.elements_np
    k = table.front_count
    leaf = el["leaf"]
    counts = np.bincount(el["patch"][leaf], minlength=k)
    size = np.sqrt(2.0 * table.areas_np[:k])
    cluster_depth = np.zeros(k)
    many = leaf & (counts[np.maximum(el["patch"], 0)] > 1)
    cluster_depth[el["patch"][many]] = el["depth"][many]
    return np.where(counts > 1, table.h / 2.0 ** cluster_depth, size)


def choose(table, sums, squares, threshold, min_size, budget, expected=None):
    """The front patches to split: ``sums`` (K, 2, 8) what each child of each patch side
    received (luminance, any unit: deposits or irradiance sums), ``squares`` (K, 2, 8) the
    sums of the squares of the deposits behind them (under a uniform density, a child's
    sum has the square root of its area's share of the patch's squares as its standard
    error, whatever the deposits' spread: a child that received nothing is tested too).
    A patch side varies where its children's densities differ from the patch's beyond
    their noise together (a chi-square test of all its children at the :data:`Z`-sigma
    level: a smooth falloff that no single child shows significantly is found too) and
    some child by more than ``threshold`` of it. The varying patches split in the order of
    the error their flat value makes (the area-weighted spread of the children's densities
    about the patch's, less its expected noise: what splitting removes), at most as many
    as keep the patches within ``budget`` (a split adds up to 3 or 7). ``expected``: given,
    the children are compared with ``expected(table, density)`` (K, 2, 8) of the patch
    sides' densities (K, 2) instead of the patch's one density: with the smooth field's averages
    over them (:func:`mi_plugins.solution.child_field.field_children`), a patch splits
    where the display is wrong, not where the light merely varies in a way the field's
    planes follow (a linear falloff splits nothing)."""
    areas = child_areas(table)[:, None, :]                          # (K, 1, 8)
    present = areas > 0
    total_area = np.maximum(areas.sum(axis=2, keepdims=True), 1e-300)
    density = np.where(present, sums / np.where(present, areas, 1.0), 0.0)
    mean = sums.sum(axis=2, keepdims=True) / total_area
    # (against the field: what the smooth display shows in each child, not the flat value)
    deviation = np.abs(density - (np.where(present, expected(table, mean[:, :, 0]), 0.0) if expected else mean))
    # a child's variance if the patch received a uniform density (the null hypothesis): its
    # area's share of the squares of all the patch's deposits (an empty child has one too)
    pooled = np.maximum(squares, 0.0).sum(axis=2, keepdims=True) * (areas / total_area)
    safe = np.where(present, areas, 1.0)
    variance = np.where(present, pooled / safe ** 2, 0.0) * (1.0 - areas / total_area)
    tested = present & (variance > 0)
    with np.errstate(over="ignore"):        # (a difference far beyond a tiny noise: infinitely significant)
        chi2 = np.where(tested, deviation ** 2 / np.where(tested, variance, 1.0), 0.0).sum(axis=2)      # (K, 2)
    df = np.maximum(tested.sum(axis=2) - 1, 1)
    varies = chi2 > chi2_quantile(df, Z)         # (no child tested: chi2 0, never above)
    varies &= (np.where(present, deviation, 0.0) > threshold * np.abs(mean)).any(axis=2)
    excess = np.where(tested, areas * (deviation ** 2 - variance), 0.0).sum(axis=2)            # (K, 2)
    score = np.where(varies, np.maximum(excess, 0.0), 0.0).sum(axis=1)
    eligible = (score > 0) & (patch_sizes(table) > 2.0 * min_size)     # (a score needs a varying side)
    order = np.argsort(-np.where(eligible, score, -1.0), kind="stable")[:int(eligible.sum())]
    room = max(0, int(budget) - table.front_count)
    return np.sort(order[:room // 3])


def chi2_quantile(df, z):
    """The chi-square quantile of ``df`` degrees of freedom at the upper tail of a normal
    ``z`` (Wilson and Hilferty's cube-root approximation)."""
    df = np.asarray(df, dtype=np.float64)
    c = 2.0 / (9.0 * df)
    return df * (1.0 - c + z * np.sqrt(c)) ** 3


def from_points(table, values, squares, counts):
    """(sums, squares) for :func:`choose` from measurements of the irradiance at uniformly
    random points of the patches, binned by child (K, 2, 8) each: their sums, the sums of
    their squares, their counts. A child's sum is its area times its points' mean (a
    count-free estimate: the number of points falling in a child does not count as
    variation), its squares those of the points' deviations from their child's mean
    (the spread within the children: a variation between them is no noise), each point
    carrying the patch's area over the patch's points: the pooled standard error is then
    the points' spread over the square root of a child's expected count."""
    areas = child_areas(table)[:, None, :]
    n = counts.sum(axis=2, keepdims=True)
    mean = values.sum(axis=2, keepdims=True) / np.maximum(n, 1)
    child_mean = np.where(counts > 0, values / np.maximum(counts, 1), mean)
    spread = np.maximum(squares - values * child_mean, 0.0)
    weight = areas.sum(axis=2, keepdims=True) / np.maximum(n, 1)
    return areas * child_mean, spread * weight * weight


def refined(table, split):
    """(new table, origin (K',): the patch of ``table`` each new front patch comes from,
    child (K',): which of its children, -1 where it was not split)."""
    new, origin = table.refined(split)
    el = new.elements_np
    leaf = el["leaf"]
    which = np.full(new.front_count, -1, np.int64)
    was_split = np.zeros(table.front_count, bool)
    was_split[np.asarray(split, np.int64)] = True
    first = np.full(new.front_count, -1, np.int64)
    leaves = np.flatnonzero(leaf)
    first[el["patch"][leaves[::-1]]] = leaves[::-1]             # one element of every new patch
    split_patch = was_split[origin]
    for k, (part, before) in enumerate(zip(new.parts, table.parts)):
        base = int(new.element_offsets[k])
        mine = np.flatnonzero(split_patch & (new.shape_index_np[:new.front_count] == k))
        if not len(mine):
            continue
        local = first[mine] - base
        grown = local >= len(before["area"])                      # a child element of a split element
        parent = part["parent"][local]
        which[mine[grown]] = local[grown] - part["child"][parent[grown]]
        octant = element_octants_of(part, local[~grown], new.h, part["depth"][local[~grown]] - 1)
        which[mine[~grown]] = octant
    return new, origin, which


def element_octants_of(part, elements, h, depth):
    """The octants of ``elements`` of ``part`` in the grid cell of their cluster at ``depth``."""
    cell = h / 2.0 ** (depth + 1)
    octant = np.floor(part["centre"][elements] / cell[:, None]).astype(np.int64) % 2
    return octant[:, 0] * 4 + octant[:, 1] * 2 + octant[:, 2]


#: the last refined table (as ``meshtable.cached_table`` keeps the last table)
_LAST = []
caches.register(_LAST.clear)


def replay(table, rounds):
    """``table`` refined by the recorded ``rounds`` (lists of split patches, each in the
    numbering of the table it was chosen on); the last result is kept for the next call."""
    if not rounds:
        return table
    key = (id(table), repr(rounds))
    if not _LAST or _LAST[0][0] != key:
        refined_table = table
        for split in rounds:
            refined_table = refined_table.refined(np.asarray(split, np.int64))[0]
        _LAST[:] = [(key, refined_table, table)]       # (the base held: its id stays unique)
    return _LAST[0][1]
