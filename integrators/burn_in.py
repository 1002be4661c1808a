"""The burn-in of the package's stochastic-iteration integrators, fitted to the scene.

The image of stochastic iteration averages the steps after a burn-in; the average misses
the power defect of the paper's eq. 20, about lambda^b / (1 - lambda)^2 after b steps
of burn-in, lambda the scene's effective albedo. Two checks keep that defect small
without the user tuning ``burn_in``:

- :func:`lengthen`: lambda measured from the chains (power continued over power carried,
  over the last steps of the default burn-in) sets the burn-in long enough for a defect
  below ``BURN_IN_BIAS``;
- :func:`drift_check`: after the planned steps, the image mean of the first and second
  half of the averaged steps are compared (:mod:`mi_plugins.convergence`); while they
  differ, the steps so far become burn-in and twice as many are averaged anew.

Both stop at the integrator's ``max_iterations``, with a ``RuntimeWarning`` naming what
was measured.
"""
import warnings

import numpy as np

from mi_plugins import convergence

#: the transient defect the fitted burn-in allows (lambda^b / (1 - lambda)^2, relative)
BURN_IN_BIAS = 1e-3


def lengthen(plugin, steps, ratios, max_iterations):
    """Lengthen the burn-in of ``steps`` (a :class:`mi_plugins.progress.Steps`) for the
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
        warnings.warn("%s: the scene's effective albedo is %.4f: a burn-in of %d steps is needed for a defect below "
                      "%.1g, but max_iterations=%d leaves room for %d; the image is darker by about %.2g %%: raise "
                      "max_iterations" % (plugin, lam, needed, BURN_IN_BIAS, max_iterations, room,
                                          100 * lam ** room / (1 - lam) ** 2), RuntimeWarning, stacklevel=3)
        needed = room
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
    if len(totals) < convergence.SEGMENTS:
        return False
    cumulative = np.array([float(t[0]) for t in totals])
    per_step = np.diff(np.concatenate([[0.0], cumulative]))
    usable = len(per_step) // convergence.SEGMENTS * convergence.SEGMENTS
    segments = per_step[len(per_step) - usable:].reshape(convergence.SEGMENTS, -1).mean(axis=1)
    if not convergence.drifting(segments):
        return False
    extra = min(2 * len(totals), max_iterations - steps.count) if extend else 0
    if extra < convergence.SEGMENTS:
        rel, t = convergence.drift(segments)
        warnings.warn("%s: after %d steps the image still drifts: the mean of the second half of the %d averaged "
                      "steps differs from the first half's by %+.2g %% (t %.1f); the scene reflects almost "
                      "everything and needs a longer burn-in: %s" % (plugin, steps.count, len(totals), 100 * rel, t,
                                                                  "raise max_iterations (now %d)" % max_iterations
                                                                  if extend else "raise burn_in and iterations"),
                      RuntimeWarning, stacklevel=3)
        return False
    steps.extend(extra)
    return True
