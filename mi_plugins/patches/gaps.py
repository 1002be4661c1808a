"""Narrow gaps: the patches at a gap's mouth, and lamps that face a surface across a gap.

A point x of a patch side is *covered* when the ray from x along that side's normal meets
a surface closer than the patch's size (``refinement.patch_sizes``): x lies in a gap
narrower than its patch (a ceiling 1 cm above a lamp facing it, the floor under an
object close above it). A patch side is at a gap's *mouth* when some of its
:data:`GRID` x :data:`GRID` points (its edges included) are covered and others not (a
ceiling patch over a lamp's rim), or when a covered point's gap ends within the patch's
size: of the four points one patch size away from it along the surface, half-way up its
gap, one does not find both the surface and its cover within that size (the lamp's own
patches along its edge).

Light in a gap changes within a few gap widths of its mouth, and light trapped between a
lamp and the surface it faces is hundreds of times brighter than the open side's: a
mouth patch's one value, the average of both, read from the open side, carries the
trapped light into the room (docs/solutions.md). Hence:

- camera paths do not read the stored light of a mouth patch
  (:meth:`mi_plugins.solution.surfaces.Surfaces.readable`): ``qmc_lighttrace``'s
  gather and every display continue the path there, as on a glossy surface (a light
  sample and a BSDF sample to the next patch). The particles are traced exactly; only
  the reading averaged them;
- the smooth field's vertices are not shared between a mouth patch and the others
  (:mod:`mi_plugins.solution.patchfield`);
- ``ray_bundle``'s solution itself carries patch averages from patch to patch, and its
  lines miss patches narrower than their spacing: it refuses a lamp whose emitting side
  faces a surface closer than half its patch size (:data:`TRAP_RATIO`) on
  :data:`TRAPPED_SHARE` of its area or more (:func:`refuse_trapped_lights`).

A misjudged point costs a continued path (noise), never a bias. Deterministic (a fixed
grid of points): the same table gives the same patches.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

#: points per patch side: a GRID x GRID grid over the patch, its edges included
GRID = 6
#: the grid's outer points lie this share of the patch inside its edges
INSET = 2e-3
#: points per lamp in the test of trapped light (an 8 x 8 stratified grid)
LAMP_POINTS = 64
#: ``ray_bundle`` refuses a lamp where this share of its points or more face a surface ...
TRAPPED_SHARE = 0.1
#: ... closer than its patch size over this (rendered anyway, a gap of a ninth of a patch
#: left +12 %, of half a patch +1 %: docs/solutions.md)
TRAP_RATIO = 2.0


def _offset(p):
    return 1e-5 * (1.0 + dr.max(dr.abs(p)))


def _probe(scene, origin, direction, reach, active=True):
    """The first hit of the ray ``origin`` + t ``direction``, 0 < t < ``reach``."""
    ray = mi.Ray3f(origin, direction)
    ray.maxt = reach                     # (Ray3f's third argument would be the time)
    return scene.ray_intersect(ray, mi.RayFlags.Minimal, False, active)


def side_points(table):
    """(interactions, the side's normal, patch size, sides, front patch of each side): the
    GRID x GRID points of every front patch side of ``table`` and of the back sides of the
    shapes that reflect on both sides."""
    from mi_plugins.base.queries import reflects_on_both_sides
    from mi_plugins.patches.refinement import patch_sizes
    count = table.front_count
    two = np.array([reflects_on_both_sides(shape) for shape in table.shapes], dtype=bool)
    backs = np.flatnonzero(two[table.shape_index_np[:count]])
    front = np.concatenate([np.arange(count), backs]).astype(np.int64)
    per = GRID * GRID
    lane = dr.arange(mi.UInt32, len(front) * per)
    which, k = lane // per, lane % per
    at = lambda i: INSET + (1.0 - 2.0 * INSET) * mi.Float(i) / (GRID - 1)
    si = table.surface_interaction(dr.gather(mi.UInt32, mi.UInt32(front.astype(np.uint32)), which),
                                   mi.Point2f(at(k % GRID), at(k // GRID)))
    normal = si.n * dr.select(which < dr.opaque(mi.UInt32, count), 1.0, -1.0)
    size = dr.gather(mi.Float, mi.Float(patch_sizes(table)[front]), which)
    return si, normal, size, len(front), front


def mouth_patches(table):
    """numpy bool (front_count,): the front patches with a side at a gap's mouth (see the
    module docstring); kept with the table (``MeshTable.derived``)."""
    return table.derived("gap mouths", lambda: _mouths(table),
                         (lambda mouth: {"mouth": mouth},
                          lambda arrays, order: arrays["mouth"].astype(bool)[slice(None) if order is None
                                                                             else order.patch]))


def _mouths(table):
    scene = table.scene
    si, normal, size, sides, front = side_points(table)
    hit = _probe(scene, si.p + normal * _offset(si.p), normal, size)
    covered = np.array(hit.is_valid(), dtype=bool).reshape(sides, -1)
    mouth = covered.any(axis=1) & ~covered.all(axis=1)           # (partly covered)
    # the ends of the gaps under the wholly covered sides: their points alone, in one
    # kernel per direction along the surface (the same kernel four times: its direction
    # an opaque index)
    test = (covered & ~mouth[:, None]).ravel()
    if test.any():
        lanes = mi.UInt32(np.flatnonzero(test).astype(np.uint32))
        pick = lambda a: dr.gather(type(a), a, lanes)
        p, n, reach = pick(si.p), pick(normal), pick(size)
        middle = p + n * (0.5 * pick(hit.t))
        frame = mi.Frame3f(n)
        ends = np.zeros(int(test.sum()), dtype=bool)
        for k in range(4):              # (four directions along the surface)
            turn = dr.opaque(mi.UInt32, k)
            along = dr.select(turn < 2, frame.s, frame.t) * dr.select(turn % 2 == 0, 1.0, -1.0)
            start = middle + along * reach
            found = _probe(scene, start, n, reach).is_valid() & _probe(scene, start, -n, reach).is_valid()
            ends |= ~np.array(found, dtype=bool)
        end_at = np.zeros(covered.size, dtype=bool)
        end_at[np.flatnonzero(test)] = ends
        mouth |= end_at.reshape(sides, -1).any(axis=1)
    out = np.zeros(table.front_count, dtype=bool)
    out[front[mouth]] = True
    return out


def trapped_lights(scene, reach):
    """[(lamp shape, facing shape id, gap, covered share)]: the shapes with an area emitter
    whose emitting side faces a surface that does not emit, closer than ``reach``, at
    TRAPPED_SHARE of their LAMP_POINTS stratified points or more (gap: the median distance
    there)."""
    found = []
    shapes = sorted((s for s in scene.shapes() if s.emitter() is not None), key=lambda s: s.id())
    if not shapes:
        return found
    grid = int(round(np.sqrt(LAMP_POINTS)))
    k = dr.arange(mi.UInt32, grid * grid)
    sample = mi.Point2f((mi.Float(k % grid) + 0.5) / grid, (mi.Float(k // grid) + 0.5) / grid)
    ids = {int(i): s.id() for i, s in zip(np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr())),
                                          scene.shapes())}
    emitting = {i for i, s in zip(np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr())), scene.shapes())
                if s.emitter() is not None}
    for shape in shapes:
        ps = shape.sample_position(0.0, sample)
        # (through numpy: a ray made of the disk's samples directly fails to compile with the
        # sphere's and cylinder's intersections in one scene, Dr.Jit 1.5.0)
        p, n = (np.broadcast_to(np.array(a, dtype=np.float64), (3, grid * grid)) for a in (ps.p, ps.n))
        p = p + n * 1e-5 * (1.0 + np.abs(p).max(axis=0))
        hit = _probe(scene, mi.Point3f(*p.astype(np.float32)), mi.Vector3f(*n.astype(np.float32)), reach)
        # (a surface that emits itself is not a dark cover: between emitting surfaces, e.g.
        # the cells of Bekaert's Sierpinski scene, the gap holds no light brighter than theirs)
        hit_shape = np.array(dr.reinterpret_array(mi.UInt32, hit.shape), dtype=np.int64)
        covered = np.array(hit.is_valid(), dtype=bool) & ~np.isin(hit_shape, list(emitting))
        if covered.mean() < TRAPPED_SHARE:
            continue
        facing = hit_shape[covered]
        values, counts = np.unique(facing, return_counts=True)
        found.append((shape, ids.get(int(values[np.argmax(counts)]), ""),
                      float(np.median(np.array(hit.t)[covered])), float(covered.mean())))
    return found


def refuse_trapped_lights(plugin, scene, patch_size):
    """Raise :class:`mi_plugins.base.errors.Unsupported` for the first lamp whose emitting side
    faces a surface closer than ``patch_size`` / TRAP_RATIO (``ray_bundle``: its solution
    carries patch averages, module docstring)."""
    from mi_plugins.base import errors
    for shape, facing, gap, share in trapped_lights(scene, patch_size / TRAP_RATIO):     # (the first, by id)
        surface = "shape '%s'" % facing if facing else "a surface (shapes Mitsuba merged: no id)"
        raise errors.Unsupported(
            plugin, "area", "the area light of shape '%s'" % shape.id(),
            "it faces %s %.3g away on %.0f %% of its area, a gap narrower than half its patches (patch_size "
            "%.3g): the light trapped there would leave the gap as the average of patches that reach past its "
            "mouth, which the bundles carry into the room" % (surface, gap, 100 * share, patch_size),
            "render this scene with 'qmc_lighttrace' or 'stochastic_ray'")
