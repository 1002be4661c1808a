"""Patches split where part of them lies in the dark (under an object resting on them,
inside a closed object, behind a wall that runs past a floor or ceiling) or where a
surface standing on them cuts them (a thin panel on a floor).

A finite-element solution keeps one irradiance per patch side: its average over the
patch. Where a part of the patch can receive no light at all (the floor under a block,
a wall's strip below the floor it meets), that average is too low for the part that is
lit, and the displays that read the solution (``smooth``, ``patches``, ``baked``) show
the lit part too dark (-10 % to -13 % in the blocks of pixels along a wall whose edges run
past the floor and the ceiling, 32 px, ``qmc_lighttrace`` against ``path``). Splitting the
patches that straddle such a boundary halves the straddling band per level; the transport
itself is unchanged (the splits only choose where the patches are finer), so a misjudged
point costs a few patches, never a bias.

A point x of a patch side is *dark* when nothing can send light to it: all but
``STRAY_RAYS`` of ``DIRECTIONS`` stratified cosine-distributed rays from x (on that side)
meet the back of a one-sided opaque surface (no ``BackSide``, ``Transmission`` or ``Null``
lobe: its back reflects and emits nothing) or leave a scene without an environment
light, and none of ``LIGHT_SAMPLES`` light samples (Mitsuba's next-event estimation,
visibility tested) reaches x (a small lamp the rays miss; point, spot and directional
lights). :func:`dark_fractions` measures it at ``POINTS`` stratified points per patch
side.

A patch side is *cut* where a surface stands across it: a thin panel or a wall on a floor
whose patch runs under it. Its parts then receive different light (the lamp behind the
panel lights one part only), and the patch's one average carries that light past the
panel: a light leak (a floor under a twosided panel with the lamp behind it: the image
in front of the panel +16 % with the gather display, +14 % and +31 % with the smooth
displays of ``qmc_lighttrace`` and ``ray_bundle``). :func:`cut_fractions` finds the points
of a side that a steep surface separates from the side's middle point. Split, the gather
display is right there again (+0.2 %); the smooth field's vertices on the panel's line
are not shared across it either (:func:`mi_plugins.solution.patchfield.separate`): +0.8 % and
+0.9 % in the smooth displays (z 1.0).

:func:`split_in_the_dark` splits the front patches with a side that is partly dark and
partly not, or partly cut (``MeshTable.refined``), ``levels`` times, within
``MAX_GROWTH`` and on tables of up to ``MAX_ELEMENTS`` elements. Deterministic (fixed
streams): the same scene and settings give the same table, which a saved solution
relies on.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import caches
from mi_plugins.base.param_docs import Row

from mi_plugins.base.sequences import hash32

#: points per patch side (a 4 x 4 stratified grid)
POINTS = 16
#: rays per point (an 8 x 8 stratified grid of the cosine-weighted hemisphere)
DIRECTIONS = 64
#: rays of a dark point that may meet something else: a surface resting on another one
#: (a block's bottom face on a floor) is found from below instead of the floor now and then
#: (4 of 4096 rays); a point that sees a lit surface through a wider opening is not dark
STRAY_RAYS = 2
#: light samples per point (next-event estimation: a lamp the rays miss, a point light)
LIGHT_SAMPLES = 4
#: the fixed seed of the measurement (a table is the same at every build)
SEED = 0x5EED
#: the segments of the cut test run this share of the patch's size above it
CUT_HEIGHT = 0.25
#: a surface crossing a patch cuts it where it stands steeper than 30 degrees to the patch's plane
CUT_COSINE = float(np.cos(np.radians(30.0)))
#: the default ``dark_levels`` of the finite-element integrators
DEFAULT_LEVELS = 2
#: the splits add at most this many times the table's patches (the largest split first)
MAX_GROWTH = 1.0
#: larger tables (elements: triangles, sub-triangles, cells) are not split: each level
#: builds the table again (a million triangles: 2 s and a second table's memory, the
#: scene's peak over 2 GB)
MAX_ELEMENTS = 250_000


def _black_backs(scene):
    """mi.Bool indexed by shape id: the shape's back neither reflects, transmits nor emits."""
    shapes = list(scene.shapes())
    ids = np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), dtype=np.int64)
    table = np.zeros(int(ids.max(initial=0)) + 2, dtype=bool)
    passes = int(mi.BSDFFlags.BackSide) | int(mi.BSDFFlags.Transmission) | int(mi.BSDFFlags.Null)
    for shape, i in zip(shapes, ids):
        bsdf = shape.bsdf()
        table[i] = bsdf is not None and not (int(bsdf.flags()) & passes)
    return mi.Bool(table)


def _side_points(table, points, only=None):
    """The ``points`` stratified points of the front patch sides of ``table`` measured
    (front sides, and back sides of the shapes that reflect on both sides; of the front
    patches ``only``, default all): (interactions, the side's normal, ray origins just off
    that side, the point's random stream, patch sides, grid width, (the measured front
    sides' patches, the measured back sides' patches))."""
    from mi_plugins.base.queries import reflects_on_both_sides
    fronts = np.arange(table.front_count) if only is None else np.asarray(only, np.int64)
    count = len(fronts)
    two = np.array([reflects_on_both_sides(shape) for shape in table.shapes], dtype=bool)
    backs = fronts[two[table.shape_index_np[fronts]]]
    patches = np.concatenate([fronts, backs]).astype(np.uint32)
    sides, grid = len(patches), int(round(np.sqrt(points)))
    n = sides * grid * grid
    lane = dr.arange(mi.UInt32, n)
    which, k = lane // (grid * grid), lane % (grid * grid)
    rng = mi.PCG32(n, initstate=mi.UInt64(hash32(SEED, 1)), initseq=mi.UInt64(lane))
    sample = mi.Point2f((mi.Float(k % grid) + rng.next_float32()) / grid,
                        (mi.Float(k // grid) + rng.next_float32()) / grid)
    si = table.surface_interaction(dr.gather(mi.UInt32, mi.UInt32(patches), which), sample)
    # (the count opaque: a literal of it would compile the kernel anew for every table)
    n_side = si.n * dr.select(which < dr.opaque(mi.UInt32, count), 1.0, -1.0)
    origin = si.p + n_side * (1e-5 * (1.0 + dr.max(dr.abs(si.p))))
    return si, n_side, origin, rng, sides, grid, (fronts, backs)


def _per_side(table, flags, sides, grid, measured):
    """numpy (front_count, 2): the share of each measured side's points where ``flags``
    holds (0 on the sides not measured)."""
    fronts, backs = measured
    share = np.array(flags, dtype=np.float64).reshape(sides, grid * grid).mean(axis=1)
    out = np.zeros((table.front_count, 2))
    out[fronts, 0] = share[:len(fronts)]
    out[backs, 1] = share[len(fronts):]
    return out


def dark_fractions(table, points=POINTS, directions=DIRECTIONS, only=None):
    """numpy (front_count, 2): the share of the points of each front patch of ``table`` (in
    its scene; of the front patches ``only``, default all, the others 0) on its front and
    back side that are dark (see the module docstring); back sides are measured on the
    shapes that reflect on both sides (``twosided``), else 0. The same whether ``table``
    keeps back-side patches or not."""
    scene = table.scene
    si, n_side, origin, rng, sides, grid, measured = _side_points(table, points, only)
    rays = int(round(np.sqrt(directions)))
    n = sides * grid * grid
    frame = mi.Frame3f(n_side)
    black = _black_backs(scene)
    open_sky = scene.environment() is None

    def body(j, lit, rng):
        go = lit <= STRAY_RAYS
        u = mi.Point2f((mi.Float(j % rays) + rng.next_float32(go)) / rays,
                       (mi.Float(j // rays) + rng.next_float32(go)) / rays)
        d = frame.to_world(mi.warp.square_to_cosine_hemisphere(u))
        hit = scene.ray_intersect(mi.Ray3f(origin, d), mi.RayFlags.Minimal, False, go)
        shape = dr.reinterpret_array(mi.UInt32, hit.shape)
        behind = hit.is_valid() & (dr.dot(hit.n, d) > 0) & dr.gather(mi.Bool, black, shape, go & hit.is_valid())
        return j + 1, lit + dr.select(go & ~(behind | (~hit.is_valid() & open_sky)), 1, 0), rng

    # loop state: the direction's number, the rays so far that met something that may send
    # light, the point's random stream
    lit = dr.while_loop((mi.UInt32(0), dr.zeros(mi.UInt32, n), rng),
                        lambda j, lit, rng: (j < rays * rays) & (lit <= STRAY_RAYS), body)[1]
    dark = lit <= STRAY_RAYS
    for j in range(LIGHT_SAMPLES):     # lights the rays may miss: small lamps, point lights
        u = mi.Point2f((j + 0.5) / LIGHT_SAMPLES, rng.next_float32(dark))
        ds, weight = scene.sample_emitter_direction(si, u, True, dark)
        dark &= ~((dr.dot(ds.d, n_side) > 0) & dr.any(mi.Color3f(weight) != 0))
    return _per_side(table, dark, sides, grid, measured)


def cut_fractions(table, points=POINTS, only=None):
    """numpy (front_count, 2), as :func:`dark_fractions` (of the front patches ``only``,
    default all): the share of each patch side's
    points cut off from one of them (the point nearest the middle of the grid) by a
    surface that crosses the patch: the segment between the two, ``CUT_HEIGHT`` of the
    patch's size above that side, meets a surface more than 30 degrees from the patch's
    plane (a wall, or a thin panel, standing on a floor whose patch runs under it, or
    just above it). The parts of such a patch receive
    different light (one side of the panel lit, the other in its shadow), which one
    average would carry across the panel: a light leak. Surfaces nearly parallel to the
    patch (its own curvature, a rug on it) do not cut it."""
    from mi_plugins.patches.refinement import patch_sizes
    scene = table.scene
    _, n_side, origin, _, sides, grid, measured = _side_points(table, points, only)
    # the segments run a quarter of the patch's size above it: a panel standing just
    # above the floor (a gap the light hardly passes) cuts the patch too
    size = patch_sizes(table)[np.concatenate(measured)]
    origin = origin + n_side * mi.Float(np.repeat(CUT_HEIGHT * size, grid * grid))
    middle = (grid // 2) * grid + grid // 2
    lane = dr.arange(mi.UInt32, sides * grid * grid)
    at = lane - lane % (grid * grid) + middle
    target = mi.Point3f(*(dr.gather(mi.Float, origin[c], at) for c in range(3)))
    return _per_side(table, crossed(scene, origin, target, n_side), sides, grid, measured)


def crossed(scene, start, end, normal):
    """mi.Bool per lane: the segment ``start`` -> ``end`` meets a surface standing steeper
    than 30 degrees to the plane of ``normal`` (a panel across a floor's patch); surfaces
    nearly parallel to it (the patch's own curvature, a rug) do not count."""
    span = end - start
    length = dr.norm(span)
    go = length > 0
    ray = mi.Ray3f(start, span / dr.select(go, length, 1.0))
    ray.maxt = length * (1.0 - 1e-4)        # (Ray3f's third argument would be the time)
    hit = scene.ray_intersect(ray, mi.RayFlags.Minimal, False, go)
    return go & hit.is_valid() & (dr.abs(dr.dot(hit.n, normal)) < CUT_COSINE)


def straddling(fractions):
    """The front patches with a side partly dark and partly not (numpy indices) of
    :func:`dark_fractions`' ``fractions``."""
    return np.flatnonzero(np.any((fractions > 0) & (fractions < 1), axis=1))


def split_in_the_dark(table, levels):
    """``table`` with the patches that straddle a dark boundary split, ``levels`` times
    (each time the straddling children of the last split are measured again; the largest
    first where they would add more than ``MAX_GROWTH`` times the table's patches); tables
    of more than ``MAX_ELEMENTS`` elements are kept as they are. The result records its
    rounds (``dark_rounds``: the split patches of each, in the numbering of the table they
    were chosen on), which a solution saves: a point where a ray grazes two touching
    surfaces can be judged otherwise by another build of Mitsuba's acceleration structure
    (another process), so a loaded solution replays the recorded splits
    (:func:`replay_dark`) instead of measuring again."""
    if table.element_count > MAX_ELEMENTS:
        return table
    base, room, only = table, int(MAX_GROWTH * table.front_count), None
    for _ in range(int(levels)):
        split = np.union1d(straddling(dark_fractions(table, only=only)), straddling(cut_fractions(table, only=only)))
        split = split[np.argsort(-table.areas_np[split], kind="stable")][:room // 3]
        if not len(split):
            break
        before = table.front_count
        table, origin = split_recorded(table, np.sort(split))
        only = np.flatnonzero(np.isin(origin, split))            # (the children, measured next)
        room -= table.front_count - before
    if table is not base:         # (a table that is its own base keeps None: not a reference cycle)
        table.dark_base = base
    return table


def replay_dark(table, rounds):
    """``table`` (unsplit) split by the recorded ``rounds`` of :func:`split_in_the_dark`;
    the last result is kept for the next call."""
    key = (id(table), repr(rounds))
    if not _REPLAYED or _REPLAYED[0][0] != key:
        _REPLAYED[:] = [(key, split_by(table, rounds), table)]          # (the base held: its id stays unique)
    return _REPLAYED[0][1]


def renumbered(table, rounds, order, step=None):
    """(rounds, table): recorded rounds of splits (front patch indices of the table each
    was chosen on, in a stored scene's shape order) in the numbering of ``table``'s
    scene, whose stored shape k is its shape ``order[k]``, and ``table`` split by them,
    round after round (``step(table, patches)``: the next round's table; default
    :func:`split_recorded`'s)."""
    step = step or (lambda t, split: split_recorded(t, split)[0])
    out = []
    for split in rounds:
        split = np.asarray(split, np.int64)
        counts = np.bincount(table.shape_index_np[:table.front_count], minlength=len(order))
        saved = np.concatenate([[0], np.cumsum(counts[order])[:-1]])       # offsets in the stored order
        k = np.searchsorted(saved, split, side="right") - 1
        here = np.sort(table.face_offsets[np.asarray(order)[k]].astype(np.int64) + split - saved[k])
        out.append([int(i) for i in here])
        table = step(table, here)
    return out, table


def split_by(table, rounds):
    """``table`` (unsplit) split by the recorded ``rounds``, its ``dark_base`` set."""
    split = table
    for patches in rounds:
        split = split_recorded(split, np.asarray(patches, np.int64))[0]
    if split is not table:
        split.dark_base = table
    return split


def with_splits(table, rounds):
    """The table of ``table``'s scene and settings whose dark splits are ``rounds`` (a
    solution's record; None: ``table`` as it is): ``table`` itself where they are its
    own, else the record replayed on its unsplit table."""
    if rounds is None or [list(r) for r in rounds] == table.dark_rounds:
        return table
    return replay_dark(table.dark_base if table.dark_base is not None else table, rounds)


_REPLAYED = []
caches.register(_REPLAYED.clear)


def split_recorded(table, split):
    """``table.refined(split)`` (the new table, the old patch of each new front patch), the
    round recorded in the new table's ``dark_rounds``."""
    rounds = table.dark_rounds + [[int(i) for i in split]]
    table, origin = table.refined(split)
    table.dark_rounds = rounds
    return table, origin


#: ``dark_levels``, read by :func:`read_levels`
DARK_ROWS = (
    Row("dark_levels", "int", "2",
        ">= 0: split the patches that lie partly in the dark (under an object resting on them, inside a closed "
        "object, past a surface they run through), that a surface standing on them cuts, or that a narrow gap "
        "separates, this many times along the boundary (``mi_plugins.patches.darkness``); 0: the patches as "
        "they are"),
)


def read_levels(p):
    """``dark_levels`` of a finite-element integrator, read with its Params ``p``."""
    return p.int("dark_levels", DEFAULT_LEVELS, lo=0, note="0: the patches as they are")
