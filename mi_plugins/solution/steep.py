"""Steep patches: where the smooth field departs from a patch's own value, the smooth
display gathers.

The smooth display reads the field fitted to the patch values
(:mod:`mi_plugins.solution.patchfield`): at every vertex a plane through the values of the
patches around it. Where the light changes sharply across a few patches (a lit strip
beside a shadow, the light that passes under a panel standing just above a floor), a
vertex shared with a bright patch carries its light into a dark one: on such a panel's
scene the shadowed floor in front of the lit strip read +566 % and the panel's face
banded by -48 % .. +47 % at 64 px, where each patch's own value (the flat display) was
within a few per cent. A patch side is *steep* when a corner's vertex value departs from
the side's own value by more than ``ratio`` times it (plus :data:`FLOOR` of the mean side
value, so that sides next to nothing do not count); the smooth display gathers there
(a light sample and a BSDF sample on to the next patch, as at crowded patches:
:meth:`mi_plugins.solution.surfaces.Surfaces.readable`), reading the stored light one
bounce further away, where such errors average out.

Measured on that panel's scene at 64 px (rows 44-47, the shadowed floor beside the
strip; 8 runs against ``path`` at 8 x 2048 spp): ``ray_bundle`` +588 % (z +52) without,
+1.1 % (z +0.1) with ``steep=0.5``; ``qmc_lighttrace`` at 100 000 paths +547 % (z +37)
without, -39 % (z -3.4) with, and dim floor rows further on -11 .. -59 % (z down to -4.5).

**Why it is off by default.** The test reads the solution's values, so which patches
gather follows their noise: a patch whose value came out low has corners far above it
and gathers, one that came out high rarely does, and the image's mean rises. With few
particles this is a bias of its own: ``qmc_lighttrace`` at 20 000 paths (the conformance
suite's setting) +0.57 % on ``cornell_mesh`` (z +9) and +2.2 % on ``mirror_lit`` (z +7.7);
at its default 100 000 paths ``cornell_mesh`` reads -0.02 % (z -0.3); on ``mirror_lit``
at 20 000 paths and 256 spp +1.75 % (z +1.5), where reading the field everywhere gives
+0.40 % and gathering everywhere +0.56 %. Requiring the departure to exceed three of
the side's standard errors too made it worse there (+4.93 %, z +7.8): a side whose value
came out high carries a large error as well, so it is kept and read. A decision from
paths independent of those displayed (a second, smaller solve) is what would let it be
on by default.
"""
import numpy as np

#: Mitsuba's luminance weights of linear RGB (mi.luminance)
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
#: departures below this share of the mean side value never make a side steep
FLOOR = 1e-3


def steep_patches(solution, table, ratio):
    """numpy bool (front patches,): the steep patches of ``solution`` on its patch
    ``table`` (module docstring), never on an emitting shape (what it shows is its
    emission); all False where ``ratio`` is 0."""
    field = solution.field
    if ratio <= 0 or field is None or field.count == 0:
        return np.zeros(0 if field is None else field.count, dtype=bool)
    flat = solution.tables.sum(axis=0)[:field.count] @ LUMINANCE                      # (K, 2)
    vertex = solution.vertex_values("tables").sum(axis=0) @ LUMINANCE                # (V, 2)
    used = (np.arange(4)[None, :] < field.corner_count[:, None]) & field.leaf[:, None]
    corner_vertex = field.vertex_ids[used].astype(np.int64)
    corner_patch = np.broadcast_to(field.element_patch[:, None], used.shape)[used]
    departure = np.zeros((field.count, 2))
    np.maximum.at(departure, corner_patch, np.abs(vertex[corner_vertex] - flat[corner_patch]))
    lit = flat > 0
    floor = FLOOR * (flat[lit].mean() if lit.any() else 0.0)
    emitting = np.array([shape.emitter() is not None for shape in table.shapes], dtype=bool)
    return np.any(departure > ratio * flat + floor, axis=1) & (floor > 0) \
        & ~emitting[table.shape_index_np[:field.count]]
