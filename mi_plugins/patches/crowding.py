"""Crowded patches: where other surfaces stand close, the smooth display gathers.

A patch's one value is the average of what its side receives. Where another surface stands
within about the patch's own size (a room's corners and wall-floor junctions, the boards
and books of a shelf, an object resting on a floor), what the side receives changes
within the patch, and the smooth display's planes through the patch values misplace it:
on the benchmark family's room, blocks of pixels along the bookshelf and the junctions
up to 3 % too dark, a per-pixel bias of 0.26 % of the image mean away from the lamps,
which more particles and camera samples do not lower (docs/solutions.md). A gather reads
the stored light one bounce further away, where such errors average out: the smooth
display gathers (a light sample and a BSDF sample on to the next patch, as on a glossy
surface or a gap's mouth: :meth:`mi_plugins.solution.surfaces.Surfaces.readable`) at the
crowded patches.

A front patch is *crowded* when more than :data:`SHARE` of the cosine-distributed rays
from :data:`POINTS` points of its front side (:data:`DIRECTIONS` stratified directions
each) meet a surface within ``reach`` times the patch's size
(``refinement.patch_sizes``). Emitting shapes are left out (they neither crowd nor are
crowded): what they show is their emission, and a lamp close to a surface traps light
between them, whose mouth ``mi_plugins.patches.gaps`` handles. Gathers near such a trap
still reach into it now and then, rarely and brightly: heavy-tailed runs there
(docs/solutions.md). Deterministic (fixed points and directions): the same table gives
the same patches; a misjudged patch costs a gather (time and some noise), never a bias.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

#: points per patch side (a 2 x 2 grid)
POINTS = 4
#: directions per point (a 4 x 4 stratified grid of the cosine-weighted hemisphere)
DIRECTIONS = 16
#: a patch is crowded when more than this share of its rays meet a surface within reach
SHARE = 0.1
#: patches per kernel of the test (rays: 64 times as many; a few hundred MB at most)
CHUNK = 1 << 16


def crowded_patches(table, reach):
    """numpy bool (front_count,): the crowded front patches of ``table`` (module
    docstring); all False where ``reach`` is 0. Kept with the table."""
    if reach <= 0 or table.front_count == 0:
        return np.zeros(table.front_count, dtype=bool)
    return table.derived("crowded %r" % float(reach), lambda: _crowded(table, float(reach)))


def _crowded(table, reach):
    from mi_plugins.patches.refinement import patch_sizes
    count = table.front_count
    sizes = mi.Float(patch_sizes(table).astype(np.float32))
    share = np.concatenate([_near_share(table, sizes, reach, start, min(CHUNK, count - start))
                            for start in range(0, count, CHUNK)])        # (blocks of patches: bounded memory)
    return (share > SHARE) & ~emitting_patches(table)


def emitting_patches(table):
    """numpy bool (front_count,): the front patches of ``table`` on emitting shapes."""
    emitting = np.array([shape.emitter() is not None for shape in table.shapes], dtype=bool)
    return emitting[table.shape_index_np[:table.front_count]]


def _near_share(table, sizes, reach, start, count):
    """numpy (count,): the share of the rays of patches start .. start + count - 1 that meet
    a non-emitting surface within reach (one kernel, the same for every block)."""
    rays = POINTS * DIRECTIONS
    side, grid = int(round(np.sqrt(POINTS))), int(round(np.sqrt(DIRECTIONS)))
    lane = dr.arange(mi.UInt32, count * rays)
    patch, j = lane // rays + dr.opaque(mi.UInt32, start), lane % rays
    point, direction = j // DIRECTIONS, j % DIRECTIONS
    cell = lambda k, n: (mi.Float(k) + 0.5) / n
    si = table.surface_interaction(patch, mi.Point2f(cell(point % side, side), cell(point // side, side)))
    local = mi.warp.square_to_cosine_hemisphere(mi.Point2f(cell(direction % grid, grid), cell(direction // grid, grid)))
    ray = si.spawn_ray(mi.Frame3f(si.n).to_world(local))
    ray.maxt = reach * dr.gather(mi.Float, sizes, patch)
    pi = table.scene.ray_intersect_preliminary(ray, False)
    near = pi.is_valid() & (pi.shape.emitter() == None)         # noqa: E711  (lamps do not crowd)
    return np.array(near, dtype=bool).reshape(count, rays).mean(axis=1)
