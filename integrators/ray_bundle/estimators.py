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
direct light is added by next-event estimation; the emission seen along the camera path
comes from :func:`~mi_plugins.integrators.camera.specular_chain`.
"""
import drjit as dr
import mitsuba as mi

from mi_plugins import seeds
from mi_plugins.integrators.camera import specular_chain
from mi_plugins.integrators.ray_bundle.direct import direct_light_mis
from mi_plugins.integrators.ray_bundle.directions import chain_directions
from mi_plugins.integrators.ray_bundle.transfer import bsdf_over_cosine


class ChainSources:
    """Every source patch contributes its value in the camera sample's chain; with
    ``skip`` (a DiffuseAverage) the averaged patches contribute nothing and neither
    does the visible point's own light (the final gathering adds them)."""

    def __init__(self, layout, skip=None):
        self.layout, self.skip = layout, skip
        self.adds_direct = skip is None

    def _use(self, tri, active):
        return active & ~self.skip.is_averaged(tri, active) if self.skip is not None else active

    def gathered(self, transport, values, src, tri, chain, side, active, rng):
        use = self._use(tri, active)
        return dr.select(use, dr.gather(mi.Color3f, values, self.layout.slot_of(tri, chain, side), use), 0.0)

    def visible(self, transport, si, tri, chain, d, incoming, active):
        use = self._use(tri, active)
        area = dr.maximum(dr.gather(mi.Float, self.layout.table.area, tri, use), 1e-30)
        result = mi.Color3f(0.0)
        for side in range(self.layout.sides):
            arriving = dr.gather(mi.Color3f, incoming, self.layout.slot_of(tri, chain, side), use) / area
            result += bsdf_over_cosine(si, arriving, d * (2.0 * side - 1.0))
        return dr.select(use, result * transport.weight, 0.0)


class AveragedSources:
    """The averaged diffuse patches contribute their average over chains and
    iterations, plus the source term of the gathered point itself (its emission, or
    with ``first_shot`` and ``gather_nee`` its direct light by next-event estimation);
    the other patches nothing."""
    adds_direct = True

    def __init__(self, average, gather_nee):
        self.average, self.gather_nee = average, gather_nee

    def gathered(self, transport, values, src, tri, chain, side, active, rng):
        use = active & self.average.is_averaged(tri, active)
        radiance = self.average.mean(tri, use)
        if not transport.first_shot:
            radiance += mi.Color3f(src.emitter(transport.scene, use).eval(src, use))
        elif self.gather_nee:
            radiance += direct_light_mis(transport.scene, src, src.bsdf(), rng, use)
        return dr.select(use, radiance, 0.0)

    def visible(self, transport, si, tri, chain, d, incoming, active):
        use = active & self.average.is_averaged(tri, active)
        # a diffuse BSDF's value does not depend on the directions: take it at the normal
        # on the side of si.wi
        wo = mi.Vector3f(0, 0, dr.sign(mi.Frame3f.cos_theta(si.wi)))
        f = mi.Color3f(si.bsdf().eval(mi.BSDFContext(), si, wo, use))
        return dr.select(use, f * self.average.mean(tri, use), 0.0)


class Estimator:
    """Common part: trace the camera pass's samples (one per chain and pixel) through
    specular chains to their visible point and splat the estimate into ``block``."""

    def __init__(self, transport, hide_emitters, seed):
        self.transport, self.hide_emitters, self.seed = transport, hide_emitters, seed

    def put(self, frame, cam, state, incoming, sources, pass_index, block):
        transport = self.transport
        chain = dr.arange(mi.UInt32, cam.count) % transport.layout.chains
        d = dr.gather(mi.Vector3f, state.dirs, chain)
        rng = seeds.pcg(cam.count, self.seed, "camera_path", pass_index)
        path = specular_chain(transport.scene, cam.ray, rng, hide_emitters=self.hide_emitters)
        si = transport.scene.ray_intersect(path.ray, path.reached)
        valid = path.reached & si.is_valid()
        value = self.reflected(si, valid, chain, d, state, incoming, sources, rng)
        if sources.adds_direct:
            if transport.first_shot:
                value += direct_light_mis(transport.scene, si, si.bsdf(path.ray), rng, valid)
            value = path.emission + path.throughput * value
        else:
            value = path.throughput * value
        frame.put_camera(cam, value, block)


class GatherEstimator(Estimator):

    def reflected(self, si, valid, chain, d, state, incoming, sources, rng):
        transport, table = self.transport, self.transport.layout.table
        bsdf = si.bsdf()
        result = mi.Color3f(0.0)
        for side in range(transport.layout.sides):
            travel = d * (1.0 - 2.0 * side)       # the radiance travels along `travel`
            wo = si.to_local(-travel)              # toward its source, on the side of si.wi
            ok = valid & (mi.Frame3f.cos_theta(wo) * mi.Frame3f.cos_theta(si.wi) > 0)
            src = transport.scene.ray_intersect(si.spawn_ray(-travel), ok)
            sky = ok & ~src.is_valid() & sources.adds_direct if transport.environment is not None else None
            tri, facing = table.side_patch(src, travel)           # the source's side facing the point
            ok &= src.is_valid() & facing
            radiance = sources.gathered(transport, state.L, src, tri, chain, side, ok, rng)
            if sky is not None:                  # the environment seen along -travel
                radiance += dr.select(sky, mi.Color3f(transport.environment.eval(src, sky)), 0.0)
                ok |= sky
            result += dr.select(ok, mi.Color3f(bsdf.eval(mi.BSDFContext(), si, wo, ok)) * radiance, 0.0)
        return result * transport.weight


class PatchEstimator(Estimator):

    def reflected(self, si, valid, chain, d, state, incoming, sources, rng):
        tri, facing = self.transport.layout.table.side_patch(si, si.to_world(si.wi))   # the side the eye sees
        return sources.visible(self.transport, si, tri, chain, d, incoming, valid & facing)


ESTIMATORS = {"gather": GatherEstimator, "patch": PatchEstimator}


def final_gathering(frame, estimator, steps, directions, sources, first, count):
    """The image of the averaged diffuse patches, the direct light and the seen emission
    (``average_diffuse``): ``count`` passes, pass k with the chains' directions of
    iteration ``first + k`` (one pass per averaged iteration that finished). Ctrl-C (or
    the progress callback) ends it after the current pass."""
    for k in steps.second_stage(count):
        m = first + k
        try:
            state = ChainDirections(chain_directions(directions[m]))
            estimator.put(frame, frame.camera_pass(), state, None, sources, m, "final")
            dr.eval(frame.state())
            frame.commit()
        except KeyboardInterrupt:
            frame.rollback()
            if k == 0:
                raise          # no finished pass: there is no image to keep
            steps.stop()
            break


class ChainDirections:
    """The part of an iteration state the final gathering needs: the directions."""

    def __init__(self, dirs):
        self.dirs, self.L = dirs, None
