"""``ray_bundle``'s view-independent solution: the irradiance every patch side receives
from the bundles, averaged over chains and averaged iterations.

In an iteration a patch receives, per unit projected area, the radiance its lines bring
along +-d; weight / A_i times that is an unbiased estimate of its irradiance (the
directions are uniform on the sphere). Taken with the shading cosine as Mitsuba's BSDFs
weigh light (the factor |cos_sh| / |cos_geo| of a white Lambertian surface at a uniformly
random point of the patch), it is what ``qmc_lighttrace`` stores: the solution's tables
read the same way for both integrators (``mi_plugins.solution.solution``). With ``first_shot``
the bundles carry the light of paths of two or more segments (the direct light is added
by the display); without it, the emission too. Orders (a finite depth) are kept apart.

The chains are summed in ``GROUPS`` groups (chain index modulo the groups): the spread of
the group means gives each patch side's standard error, where the chains are independent
(not with ``share_diffuse``, whose chains continue from one shared mean: no error then).
"""
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.render.frame import SPLAT_MODE
from mi_plugins.solution.patch_light import white
from mi_plugins.integrators.ray_bundle.transfer import bsdf_over_cosine

#: groups of chains whose spread is the solution's error (fewer when there are fewer chains)
GROUPS = 8


@dataclass
class IrradianceState:
    """Per (group, front patch, side): sums per order; the iterations added; the random
    stream of the patch points."""
    sums: list
    count: mi.Float
    rng: mi.PCG32


class IrradianceAverage:
    """The average irradiance of ``layout``'s patch sides (``weight``: solid angle per
    global direction and side)."""

    def __init__(self, layout, weight, rng, independent=True):
        table = layout.table
        self.layout, self.weight = layout, float(weight)
        self.groups = max(1, min(GROUPS, layout.chains)) if independent else 1
        self.fronts = table.front_count
        back = np.arange(table.count) >= table.front_count
        self.target = mi.UInt32((table.front_of_np * 2 + back).astype(np.uint32))
        self.bsdf = white(table)        # (held: a frozen step finds the plugins it calls among its inputs)
        self.state = IrradianceState([], dr.opaque(mi.Float, 0.0), rng)
        self.reset()

    def reset(self):
        """Forget every iteration added (a burn-in that goes on)."""
        size = self.groups * self.fronts * 2
        self.state.sums = [dr.zeros(mi.Color3f, size) for _ in range(self.layout.orders)]
        self.state.count = dr.opaque(mi.Float, 0.0)
        dr.make_opaque(self.state.sums)

    def add(self, dirs, incoming):
        """Add one iteration of every chain: ``incoming`` (per order, per lane) along the
        chains' directions ``dirs``."""
        layout, st, table = self.layout, self.state, self.layout.table
        slot = dr.arange(mi.UInt32, layout.slots)
        tri, chain = slot % layout.count, slot // layout.count
        si = table.surface_interaction(tri, mi.Point2f(st.rng.next_float32(), st.rng.next_float32()))
        facing = dr.select(tri < table.front_count, 1.0, -1.0)
        si.wi = si.to_local(si.n * facing)
        d = dr.gather(mi.Vector3f, dirs, chain)
        area = dr.maximum(dr.gather(mi.Float, table.area, tri), 1e-30)
        bsdf = self.bsdf
        # arriving along +d it comes from -d, along -d from +d
        cosines = [dr.pi * self.weight * bsdf_over_cosine(si, bsdf, d * (2.0 * j - 1.0)).x / area
                   for j in range(layout.sides)]
        target = (chain % self.groups) * (self.fronts * 2) + dr.gather(mi.UInt32, self.target, tri)
        for k, inc in enumerate(incoming):
            value = sum((cosines[j] * dr.gather(mi.Color3f, inc, layout.slot_of(tri, chain, j))
                         for j in range(layout.sides)), mi.Color3f(0.0))
            dr.scatter_add(st.sums[k], value, target, mode=SPLAT_MODE)
        st.count = st.count + 1.0

    def numpy(self):
        """(tables (T, K, 2, 3): cumulative over the orders, standard error of the last (K, 2,
        3) or None with one group), the average over chains and iterations."""
        count = max(float(self.state.count[0]), 1.0)
        per_group = np.array([(self.layout.chains - g + self.groups - 1) // self.groups for g in range(self.groups)],
                             dtype=np.float64)
        orders = [np.array(s, dtype=np.float64).T.reshape(self.groups, self.fronts, 2, 3) for s in self.state.sums]
        cumulative = np.cumsum(np.stack(orders), axis=0)                          # (T, G, K, 2, 3)
        means = cumulative / (count * per_group)[None, :, None, None, None]
        tables = (cumulative.sum(axis=1) / (count * self.layout.chains))
        error = None
        if self.groups > 1:
            error = means[-1].std(axis=0, ddof=1) / np.sqrt(self.groups)
        return tables, error
