"""The particle deposits of ``qmc_lighttrace``: layers by hit count, limits, read tables.

A camera path that has used u segments when it reaches a diffuse point y may add
light paths of at most D - u segments there (D: Mitsuba's ``max_depth``). y's direct
light (1 segment) is computed at y by next-event estimation; what is stored is the
light of particles at their hit k >= 2. So the deposits are kept in *layers by hit
count*: layer 0 holds the hits k = 1 (reported in ``reflected_radiance``, never read),
layer j >= 1 the hits k = j + 1, and the read tables are cumulative: table t holds
k = 2 .. t + 2. With D unbounded (-1) there is one read layer for every k >= 2.

Sums are 64-bit signed fixed point (order-independent integer atomics, negative
emission included). Limits: a layer count x patch count of at most
:data:`MAX_PATCH_LAYERS`, and the memory they take must fit in half the available memory.
"""

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base.limits import available_memory
from mi_plugins.base.params import parameter_error

#: at most this many (patch, layer) pairs (each holds 2 sides x 3 channels)
MAX_PATCH_LAYERS = 1 << 24
#: bytes per (patch, layer): int64 deposits, their float64 copy and sum, float32 read table
BYTES_PER_PATCH_LAYER = 6 * (8 + 8 + 8 + 4)


class Layers:
    """Layer layout for Mitsuba's ``max_depth`` D (-1: unbounded); ``visible``: camera
    paths read the stored light at the visible point itself (the display modes of a
    solution), not only after a gather segment."""

    #: the tables hold the light of k >= 2 hits only (the direct light: next-event estimation)
    carries_direct = False

    def __init__(self, max_depth, visible=False):
        self.unbounded = max_depth < 0
        # the largest hit count a camera path can still read: k <= D - 2 (camera + gather
        # segment), D - 1 where the visible point reads
        self.max_hits = None if self.unbounded else max(max_depth - (1 if visible else 2), 1)
        self.count = 2 if self.unbounded else self.max_hits
        self.tables = 1 if self.unbounded else max(self.count - 1, 0)

    def layer(self, hits):
        """Layer of the k-th hit (UInt32 ``hits`` = k >= 1)."""
        return dr.minimum(hits, self.count) - 1

    def read_table(self, budget):
        """(table index, readable) for paths that may still add ``budget`` light segments
        (Int32 per lane): the table of k = 2 .. min(budget, max_hits)."""
        if self.unbounded:
            return dr.zeros(mi.UInt32, dr.width(budget)), budget >= 2
        top = dr.minimum(budget, self.max_hits)
        return mi.UInt32(dr.maximum(top - 2, 0)), top >= 2

    def tables_from(self, irradiance):
        """Cumulative read tables (tables, K, 2, 3) from per-layer values (count, K, 2, 3)."""
        if self.unbounded:
            return irradiance[1:2]
        return np.cumsum(irradiance[1:], axis=0)


def check_memory(plugin, layers, patches, max_depth):
    """Refuse (a Params-style error naming max_depth) before any work when the layers of
    ``patches`` patches exceed MAX_PATCH_LAYERS or half of the available memory."""
    pairs = layers.count * patches
    need = pairs * BYTES_PER_PATCH_LAYER
    available = available_memory()
    if pairs > MAX_PATCH_LAYERS or (available is not None and need > available // 2):
        raise parameter_error(plugin, [("max_depth", max_depth)], (
            "-1 (unbounded: 2 layers) or a depth whose %d deposit layers x %d patches fit: at most %d "
            "patch layers (%d here) and half the available memory (%.0f MiB needed, %s); use max_depth=-1, a "
            "smaller max_depth or a larger patch_size" % (layers.count, patches, MAX_PATCH_LAYERS, pairs,
                                                          need / 2 ** 20, "%.0f MiB available" % (available / 2 ** 20)
                                                          if available is not None else "unknown available")))


class FixedPoint:
    """Signed 64-bit fixed-point sums of ``slots`` values: ``scale`` units per unit of
    power. :meth:`fits` tells afterwards whether the sum of all |values| stayed below
    2^61 units, so that no slot can have overflowed (else trace again with
    :meth:`rescaled`)."""

    LIMIT = 2.0 ** 61
    #: the largest scale (a float32 of the kernels: 2^128 would be infinite)
    MAX_SCALE = 2.0 ** 100

    def __init__(self, slots, scale):
        self.scale = float(scale)
        self.sums = dr.zeros(mi.Int64, slots)

    @staticmethod
    def scale_for(bound):
        """A power of two such that ``bound`` (a guess of the sum of all |values|) fits."""
        return min(2.0 ** np.floor(np.log2(FixedPoint.LIMIT / max(float(bound), 1e-30))), FixedPoint.MAX_SCALE)

    def add(self, value, slot, active):
        """Add Float ``value`` to ``slot`` where ``active``."""
        units = mi.Int64(dr.round(value * dr.opaque(mi.Float, self.scale)))
        dr.scatter_reduce(dr.ReduceOp.Add, self.sums, units, slot, active)

    def fits(self, total_abs):
        return float(total_abs) * self.scale < self.LIMIT

    def values(self):
        return np.array(self.sums, dtype=np.int64).astype(np.float64) / self.scale
