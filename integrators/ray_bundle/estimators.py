"""Image estimates of ``ray_bundle``: what a camera sample sees of the patch radiances.

Two estimators, chosen once per render by the ``estimate`` parameter:

- :class:`GatherEstimator` ('gather', the paper's per-pixel variant): at the visible
  point, reflect toward the eye the radiance arriving along +-d from the patch seen in
  the opposite direction (or from the environment emitter, when the bundles carry it);
- :class:`PatchEstimator` ('patch'): reflect the visible patch's incoming power of the
  bundle (sum_j A(i,j,+-d) L[j] / A_i).

Where that radiance comes from is a *source* object: :class:`ChainSources` (every
patch's value in the sample's chain: the paper's estimate, optionally skipping averaged
patches) or :class:`AveragedSources` (the per-triangle averages of ``average_diffuse``,
plus the source term of the gathered point). With ``first_shot`` the visible point's
direct light through its smooth lobes is added by next-event estimation, and the light
reaching it through its delta lobes (the specular layer of ``plastic``) by Mitsuba's
``path`` (:class:`~mi_plugins.render.handoff.Handoff`); the emission seen along the
camera path comes from :func:`~mi_plugins.render.camera.specular_chain`.

Depth: with a finite ``max_depth`` every lane takes the orders of the stored radiance
that its path may still reach: order k read at a visible point after ``used`` path
segments makes a path of used + 2 + k segments with ``first_shot`` (the order-0 value is
the direct light reflected there), used + 1 + k without (order 0 is emission).
"""
import drjit as dr
import mitsuba as mi

from mi_plugins.solution import display
from mi_plugins.render.camera import specular_chain
from mi_plugins.render.frame import coverage
from mi_plugins.render.handoff import Handoff
from mi_plugins.integrators.ray_bundle.direct import direct_light_mis
from mi_plugins.integrators.ray_bundle.transfer import bsdf_over_cosine

#: the lobes the estimators cover at a visible point (the delta lobes are handed off)
SMOOTH_ONLY = mi.BSDFContext(mi.TransportMode.Radiance, int(mi.BSDFFlags.All) & ~int(mi.BSDFFlags.Delta))


def has_non_smooth_scalar(bsdf):
    """The BSDF has a delta lobe (a delta lobe of a mixed BSDF is handed off)."""
    return bool(int(bsdf.flags()) & int(mi.BSDFFlags.Delta))


def orders_upto(values, hi, active, read):
    """Sum over the orders k <= ``hi`` (per lane; None: all) of ``read(values[k], use)``."""
    total = mi.Color3f(0.0)
    for k, v in enumerate(values):
        use = active if hi is None else mi.Bool(active) & (mi.Int32(k) <= hi)
        total += dr.select(use, read(v, use), 0.0)
    return total


class ChainSources:
    """Every source patch contributes its value in the camera sample's chain; with
    ``skip`` (a DiffuseAverage) the averaged patches contribute nothing and neither
    does the visible point's own light (the final gathering adds them)."""

    def __init__(self, layout, skip=None):
        self.layout, self.skip = layout, skip
        self.adds_direct = skip is None

    def _use(self, tri, active):
        return active & ~self.skip.is_averaged(tri, active) if self.skip is not None else active

    def gathered(self, transport, state, src, tri, chain, side, active, rng, hi):
        """The radiance ``src`` sends toward the gathering point: the source term at the
        point itself (order 0) and the bundles' part of its patch in the chain."""
        use = self._use(tri, active)
        slot = self.layout.slot_of(tri, chain, side)
        own = use if hi is None else use & (hi >= 0)
        point = transport.point_source(src, own, rng) if transport.point_sources else None
        orders = transport.carried(state, slot, point, use)
        return orders_upto(orders, hi, use, lambda v, ok: v)

    def visible(self, transport, si, tri, chain, d, incoming, active, hi):
        use = self._use(tri, active)
        area = dr.maximum(dr.gather(mi.Float, self.layout.table.area, tri, use), 1e-30)
        bsdf, result = si.bsdf(), mi.Color3f(0.0)
        for side in range(self.layout.sides):
            f = bsdf_over_cosine(si, bsdf, d * (2.0 * side - 1.0), use) / area
            slot = self.layout.slot_of(tri, chain, side)
            result += f * orders_upto(incoming, hi, use, lambda v, ok: dr.gather(mi.Color3f, v, slot, ok))
        return dr.select(use, result * transport.weight, 0.0)


class AveragedSources:
    """The averaged diffuse patches contribute their average over chains and
    iterations, plus the source term of the gathered point itself (its emission, or
    with ``first_shot`` and ``gather_nee`` its direct light by next-event estimation);
    the other patches nothing. ``lo``: the first order the averages hold that the
    gathered point does not add itself (finite depth)."""
    adds_direct = True

    def __init__(self, average, gather_nee, lo=0):
        self.average, self.gather_nee, self.lo = average, gather_nee, lo

    def gathered(self, transport, state, src, tri, chain, side, active, rng, hi):
        use = active & self.average.is_averaged(tri, active)
        radiance = self.average.mean(tri, use, self.lo, hi)
        own = use if hi is None else use & (hi >= 0)
        if not transport.first_shot:
            radiance += dr.select(own, mi.Color3f(src.emitter(transport.scene, own).eval(src, own)), 0.0)
        elif self.gather_nee:
            radiance += direct_light_mis(transport.scene, src, src.bsdf(), rng, own)
        return dr.select(use, radiance, 0.0)

    def visible(self, transport, si, tri, chain, d, incoming, active, hi):
        use = active & self.average.is_averaged(tri, active)
        # a diffuse BSDF's value does not depend on the directions: take it at the normal
        # on the side of si.wi
        wo = mi.Vector3f(0, 0, dr.sign(mi.Frame3f.cos_theta(si.wi)))
        f = mi.Color3f(si.bsdf().eval(mi.BSDFContext(), si, wo, use))
        return dr.select(use, f * self.average.mean(tri, use, 0, hi), 0.0)


class Estimator:
    """Common part: trace the camera pass's samples (one per chain and pixel) through
    specular chains to their visible point and splat the estimate into ``block``.
    ``max_depth``: Mitsuba's (-1: unbounded)."""

    def __init__(self, transport, hide_emitters, max_depth=-1):
        self.transport, self.hide_emitters, self.max_depth = transport, hide_emitters, int(max_depth)
        self.edges = None        # (shifts, mask, pixels) of display.edge_pixels: further rays there
        self.group = transport.layout.chains      # chains per camera pass (fewer: see limits.camera_group)
        needed = any(s.bsdf() is not None and has_non_smooth_scalar(s.bsdf()) for s in transport.scene.shapes())
        self.handoff = Handoff(self.max_depth, max_used=max(self.max_depth, 1)) if needed else None

    def order_limit(self, used):
        """Per lane: the highest order a visible point after ``used`` segments may read
        (None: unbounded)."""
        if self.max_depth < 0:
            return None
        return mi.Int32(self.max_depth) - mi.Int32(used) - (2 if self.transport.first_shot else 1)

    def put(self, frame, cam, state, incoming, sources, rng_seed, block, chain_offset=0):
        """Estimate one camera pass of a group of ``self.group`` chains from
        ``chain_offset`` (``per_pixel`` = group consecutive lanes per pixel)."""
        transport, scene, depth = self.transport, self.transport.scene, self.max_depth
        chain = chain_offset + dr.arange(mi.UInt32, cam.count) % self.group
        d = dr.gather(mi.Vector3f, state.dirs, chain)
        rng = mi.PCG32(cam.count, initstate=rng_seed, initseq=mi.UInt64(dr.arange(mi.UInt32, cam.count)))
        path = specular_chain(scene, cam.ray, rng, max_depth=depth, hide_emitters=self.hide_emitters)
        si = path.si if path.si is not None else scene.ray_intersect(path.ray, path.reached)
        valid = path.reached & si.is_valid()
        used = path.depth + 1
        hi = self.order_limit(used)
        value = self.reflected(si, valid, chain, d, state, incoming, sources, rng, hi)
        if sources.adds_direct:
            bsdf = si.bsdf(path.ray)
            nee = valid if depth < 0 else valid & (used + 1 <= depth)
            if transport.first_shot:
                value += direct_light_mis(scene, si, bsdf, rng, nee, SMOOTH_ONLY)
            if self.handoff is not None:  # the delta lobes of a mixed BSDF (plastic's specular layer)
                value += self.handoff.sample(scene, cam.sampler, si, bsdf, used if depth >= 0 else 1, valid,
                                             max_used=max(depth, 1))
            value = path.emission + path.throughput * value
            value = display.with_edges(frame, cam, path, self.edges, value, rng_seed, block)
        else:
            value = path.throughput * value
        covered = None
        if mi.has_flag(frame.film.flags(), mi.FilmFlags.Alpha):
            covered = coverage(scene, path.surface, self.hide_emitters)
        frame.put_camera(cam, value, block, coverage=covered)



class GatherEstimator(Estimator):

    def reflected(self, si, valid, chain, d, state, incoming, sources, rng, hi):
        transport, table = self.transport, self.transport.layout.table
        bsdf = si.bsdf()
        transmits = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Transmission)
        result = mi.Color3f(0.0)
        for side in range(transport.layout.sides):
            travel = d * (1.0 - 2.0 * side)       # the radiance travels along `travel`
            wo = si.to_local(-travel)              # toward its source
            ok = valid & ((mi.Frame3f.cos_theta(wo) * mi.Frame3f.cos_theta(si.wi) > 0) | transmits)
            src = transport.scene.ray_intersect(si.spawn_ray(-travel), ok)
            sky = ok & ~src.is_valid() & sources.adds_direct if transport.environment is not None else None
            if sky is not None and hi is not None:
                sky &= hi >= 0                     # the environment is emission: order 0
            tri, facing = table.side_patch(src, travel)           # the source's side facing the point
            ok &= src.is_valid() & facing
            radiance = sources.gathered(transport, state, src, tri, chain, side, ok, rng, hi)
            if sky is not None:                  # the environment seen along -travel
                radiance += dr.select(sky, mi.Color3f(transport.environment.eval(src, sky)), 0.0)
                ok |= sky
            result += dr.select(ok, mi.Color3f(bsdf.eval(mi.BSDFContext(), si, wo, ok)) * radiance, 0.0)
        return result * transport.weight


class PatchEstimator(Estimator):

    def reflected(self, si, valid, chain, d, state, incoming, sources, rng, hi):
        tri, facing = self.transport.layout.table.side_patch(si, si.to_world(si.wi))   # the side the eye sees
        return sources.visible(self.transport, si, tri, chain, d, incoming, valid & facing, hi)


ESTIMATORS = {"gather": GatherEstimator, "patch": PatchEstimator}
