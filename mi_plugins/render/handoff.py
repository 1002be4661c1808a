"""Light seen through the delta and null lobes of a surface, estimated by Mitsuba's ``volpath``.

The package's estimators cover the *smooth* lobes of the surface a camera path reaches:
``stochastic_ray`` connects light paths to the camera through them, ``ray_bundle`` and
``qmc_lighttrace`` reflect their stored radiance through them. A surface can also
reflect, refract or let light pass through *delta* lobes (``conductor``, ``dielectric``,
``thindielectric``, the specular layer of ``plastic``) and *null* lobes (``null``,
``mask``, the polarizers of RGB variants); no connection or stored value can reach
those. :class:`Handoff` completes the estimate: it samples the surface's full BSDF once,
and where the sample falls on a delta or null lobe it continues the path with Mitsuba's
own ``volpath`` integrator (``Integrator.sample`` on the sampled ray, drawing from the
camera pass's sampler) and weights the result by the sample's weight. ``volpath``, not
``path``: its light samples pass null surfaces (``mask``, ``null``) with their
transmittance, where Mitsuba 3.9.1's ``path`` counts them as blockers and renders the
light behind them too dark (docs/findings.md); without media the two are the same
estimator otherwise. Where a smooth
lobe is sampled it adds nothing (the integrator's estimator covers those lobes in full),
so the sum is an unbiased estimate of every lobe's share.

Depth: the hand-off ray starts the path's segment ``used + 1``; with a finite
``max_depth`` (Mitsuba's meaning) the ``path`` integrator that continues it gets
``max_depth - used``.
"""
import drjit as dr
import mitsuba as mi

#: BSDF lobes the integrators' own estimators cannot follow
NON_SMOOTH = mi.BSDFFlags.Delta


def has_non_smooth(bsdf):
    """Per lane: the BSDF has a delta or null lobe."""
    return mi.has_flag(bsdf.flags(), NON_SMOOTH)


class Handoff:
    """Continue camera paths through non-smooth lobes with Mitsuba's ``volpath``."""

    def __init__(self, max_depth=-1, max_used=1):
        self.max_depth = int(max_depth)
        self._paths = {}
        # made now, for every depth ``sample`` can ask for: a plugin created while a
        # kernel is being traced changes that trace, so a render's first kernels would
        # differ from its later renders' and be compiled twice (and frozen steps must
        # not create plugins)
        for used in ([1] if self.max_depth < 0 else range(1, max(int(max_used), 1) + 1)):
            self._path(-1 if self.max_depth < 0 else self.max_depth - used)

    def _path(self, depth):
        if depth not in self._paths:
            self._paths[depth] = mi.load_dict({"type": "volpath", "max_depth": int(depth)})
        return self._paths[depth]

    def sample(self, scene, sampler, si, bsdf, used, active, max_used=1):
        """The light reaching ``si.wi`` through the non-smooth lobes at ``si`` (Color3f);
        ``used``: segments of the camera path up to ``si`` (an int, or UInt32 per lane
        with values in 1 .. ``max_used``); ``sampler``: the camera pass's sampler."""
        active = mi.Bool(active) & si.is_valid() & has_non_smooth(bsdf)
        if self.max_depth >= 0:
            active &= mi.UInt32(used) < self.max_depth
        bs, weight = bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(active), sampler.next_2d(active), active)
        go = active & mi.has_flag(bs.sampled_type, NON_SMOOTH) & dr.any(mi.Color3f(weight) != 0)
        ray = si.spawn_ray(si.to_world(bs.wo))
        if self.max_depth < 0 or isinstance(used, int):
            depth = -1 if self.max_depth < 0 else self.max_depth - int(used)
            radiance = self._path(depth).sample(scene, sampler, ray, None, go)[0]
        else:
            radiance = mi.Color3f(0.0)
            for k in range(1, min(self.max_depth, int(max_used) + 1)):   # the path's depth left, per lane
                lanes = go & (used == k)
                radiance += dr.select(lanes, mi.Color3f(self._path(self.max_depth - k).sample(
                    scene, sampler, ray, None, lanes)[0]), 0.0)
        return dr.select(go, mi.Color3f(weight) * mi.Color3f(radiance), 0.0)
