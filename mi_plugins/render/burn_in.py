"""The burn-in of the package's stochastic-iteration integrators, fitted to the scene.

The image of stochastic iteration averages the steps after a burn-in; the average misses
the power defect of the paper's eq. 20, about lambda^b / (1 - lambda)^2 after b steps
of burn-in, lambda the scene's effective albedo. Two checks keep that defect small
without the user tuning ``burn_in``:

- :func:`lengthen`: lambda measured from the chains (power continued over power carried,
  over the last steps of the default burn-in) sets the burn-in long enough for a defect
  below ``BURN_IN_BIAS``;
- :func:`drift_check`: after the planned steps, the image mean of the first and second
  half of the averaged steps are compared (:mod:`mi_plugins.render.burn_in`); while they
  differ, the steps so far become burn-in and twice as many are averaged anew.

Where ``max_iterations`` leaves too little room, the render is refused
(:class:`mi_plugins.base.errors.NotConverged`, naming what was measured and the steps needed)
instead of returning a darker image; a drift left with a burn-in the user chose is warned of.
"""
import warnings

import numpy as np

from mi_plugins.render import burn_in
from mi_plugins.base import errors

#: the transient defect the fitted burn-in allows (lambda^b / (1 - lambda)^2, relative)
BURN_IN_BIAS = 1e-3


def lengthen(plugin, steps, ratios, max_iterations):
    """Lengthen the burn-in of ``steps`` (a :class:`mi_plugins.render.progress.Steps`) for the
    effective albedo measured from ``ratios`` (pairs of evaluated Floats: power carried,
    power continued); returns the albedo."""
    carried = sum(float(c[0]) for c, _ in ratios)
    lam = sum(float(k[0]) for _, k in ratios) / carried if carried > 0 else 0.0
    if not 0.0 < lam < 1.0:
        return lam
    needed = int(np.ceil(np.log(BURN_IN_BIAS * (1.0 - lam) ** 2) / np.log(lam)))
    averaged = steps.count - steps.state.burn_in
    room = max_iterations - averaged
    if needed > room:
        raise errors.NotConverged(
            plugin, "the scene's effective albedo is %.4f: a burn-in of %d steps is needed for a defect below %.1g, and "
                    "%d leave the image darker by about %.2g %%" % (lam, needed, BURN_IN_BIAS, room,
                                                                    100 * lam ** room / (1 - lam) ** 2),
            needed + averaged, max_iterations, "render this scene with 'qmc_lighttrace', whose particles need no "
                                               "burn-in")
    if needed > steps.state.burn_in:
        steps.extend(needed - steps.state.burn_in, restart_average=False)
        steps.state.burn_in = needed
        steps.state.planned_averaged = averaged
    return lam


def drift_check(plugin, steps, totals, max_iterations, extend=True):
    """After the planned steps: True when the averaged image still drifts and ``steps``
    was extended (the caller then clears its image and ``totals``: evaluated Floats,
    the image's running sum after each averaged step); a drift left at
    ``max_iterations``, or found with ``extend=False`` (a burn-in the user chose), is
    warned of."""
    if len(totals) < burn_in.SEGMENTS:
        return False
    cumulative = np.array([float(t[0]) for t in totals])
    per_step = np.diff(np.concatenate([[0.0], cumulative]))
    usable = len(per_step) // burn_in.SEGMENTS * burn_in.SEGMENTS
    segments = per_step[len(per_step) - usable:].reshape(burn_in.SEGMENTS, -1).mean(axis=1)
    if not burn_in.drifting(segments):
        return False
    extra = min(2 * len(totals), max_iterations - steps.count) if extend else 0
    if extra < burn_in.SEGMENTS:
        rel, t = burn_in.drift(segments)
        what = ("after %d steps the image still drifts: the mean of the second half of the %d averaged steps differs "
                "from the first half's by %+.2g %% (t %.1f); the scene reflects almost everything and needs a longer "
                "burn-in" % (steps.count, len(totals), 100 * rel, t))
        if extend:
            raise errors.NotConverged(plugin, what, steps.count + 2 * len(totals), max_iterations,
                                       "render this scene with 'qmc_lighttrace', whose particles need no burn-in")
        warnings.warn("%s: %s: raise burn_in and iterations" % (plugin, what), RuntimeWarning, stacklevel=3)
        return False
    steps.extend(extra)
    return True
