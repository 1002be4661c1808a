"""The burn-in of the package's stochastic-iteration integrators: one model of how an
average taken too early falls short, and the checks that fit the burn-in to the scene.

Started from the emitted light, the iteration's power grows toward the solution like
P_m = P - c lambda^m (lambda: the share of the power the scene reflects, the paper's
contraction ratio, eq. 20); an average of the steps after a burn-in of b misses about
lambda^b / (1 - lambda)^2 of it. Both integrators measure lambda from their own chains
and extend the burn-in until the predicted shortfall is small; where their
``max_iterations`` leaves too little room, the render is refused
(:class:`mi_plugins.base.errors.NotConverged`, naming what was measured and the steps
needed) instead of returning a darker image.

- ``stochastic_ray``: :func:`lengthen` (lambda from the power continued over the power
  carried, over the last steps of the default burn-in; a shortfall below
  ``BURN_IN_BIAS``) and :func:`drift_check` (after the planned steps, the image means of
  the first and second half of the averaged steps, :func:`drift`; while they differ, the
  steps so far become burn-in and twice as many are averaged anew). A drift left with a
  burn-in the user chose is warned of.
- ``ray_bundle``: :func:`verdict` on the chains' total power per averaged iteration
  (the reflected share gives lambda through a scalar model, :func:`scalar_lambda`; the
  growth between the halves of the window is measured too) predicts the average's bias,
  and :meth:`Verdict.burn_in_needed` the further burn-in for ``BIAS_TOLERANCE``.
"""
import math
import warnings
from dataclasses import dataclass

import numpy as np

from mi_plugins.base import errors

#: the transient defect the fitted burn-in of ``stochastic_ray`` allows (lambda^b / (1 - lambda)^2, relative)
BURN_IN_BIAS = 1e-3
#: segments the averaged steps are cut into for the drift check (half of them per half)
SEGMENTS = 8
#: relative difference of the halves' means below which a drift is accepted
DRIFT_TOLERANCE = 0.005
#: and the number of standard errors it must exceed to count (the noise is estimated from
#: few segments: a t statistic with about 4 degrees of freedom, beyond 6 in 0.4 % of
#: converged renders, which then only run longer)
DRIFT_Z = 6.0
#: ``ray_bundle``: growth of the mean beyond this many standard errors counts
GROWTH_Z = 3.0
#: ``ray_bundle``: a predicted relative bias of the image above this is not converged
BIAS_TOLERANCE = 0.01
#: ``ray_bundle``: the default max_iterations, times the planned iterations of the render
EXTENSION_CAP = 8


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
        steps.lengthen_burn_in(needed)
    return lam


def drift_check(plugin, steps, totals, max_iterations, extend=True):
    """After the planned steps: True when the averaged image still drifts and ``steps``
    was extended (the caller then clears its image and ``totals``: evaluated Floats,
    the image's running sum after each averaged step); a drift left at
    ``max_iterations``, or found with ``extend=False`` (a burn-in the user chose), is
    warned of."""
    if len(totals) < SEGMENTS:
        return False
    cumulative = np.array([float(t[0]) for t in totals])
    per_step = np.diff(np.concatenate([[0.0], cumulative]))
    usable = len(per_step) // SEGMENTS * SEGMENTS
    segments = per_step[len(per_step) - usable:].reshape(SEGMENTS, -1).mean(axis=1)
    if not drifting(segments):
        return False
    extra = min(2 * len(totals), max_iterations - steps.count) if extend else 0
    if extra < SEGMENTS:
        rel, t = drift(segments)
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


def drift(values):
    """(relative drift of the second half's mean over the first's, its t statistic) of
    the per-segment image means ``values`` (an even count, at least 4). The segments'
    noise is estimated from their second differences, which a steady drift (a trend
    linear over the render) leaves out: sigma^2 = mean(d2^2) / 6."""
    v = np.asarray(values, dtype=np.float64)
    half = len(v) // 2
    a, b = v[:half], v[half:2 * half]
    scale = max(abs(v.mean()), 1e-30)
    d2 = v[2:] - 2.0 * v[1:-1] + v[:-2]
    se = math.sqrt(np.mean(d2 * d2) / 6.0 * 2.0 / half)
    diff = b.mean() - a.mean()
    return diff / scale, (diff / se if se > 0 else (math.inf if diff else 0.0))


def drifting(values):
    """True when the per-segment means ``values`` still drift (:func:`drift`: beyond ``DRIFT_TOLERANCE`` and ``DRIFT_Z``)."""
    rel, t = drift(values)
    return abs(rel) > DRIFT_TOLERANCE and abs(t) > DRIFT_Z


@dataclass
class Verdict:
    growth: float          # relative growth of the mean between the halves
    z: float               # growth / its standard error
    reflectance: float     # lambda of the scalar model
    bias: float            # predicted relative bias of the average (negative: too dark)
    averaged: int
    start: int             # iterations before the window

    @property
    def converged(self):
        return -self.bias <= BIAS_TOLERANCE

    def burn_in_needed(self):
        """Further burn-in iterations (after this window, which becomes burn-in too) for
        the model's bias of a window of the same length to fall to half the tolerance."""
        lam, n = self.reflectance, self.averaged
        if lam <= 0:
            return 1
        lam = min(lam, 0.9995)
        target = 0.5 * BIAS_TOLERANCE * n * (1 - lam) / (1 - lam ** n)
        first = int(np.ceil(np.log(target) / np.log(lam) - 1))      # the new window's first iteration
        return max(first - (self.start + n), 1)

    def text(self):
        return ("the chains' total power grew by %.2g %% (z = %.1f) from the first to the second half of the %d "
                "averaged iterations, and the share of it the scene reflects (%.3f: its contraction ratio) leaves "
                "the average about %.2g %% too low" % (100 * self.growth, self.z, self.averaged, self.reflectance,
                                                       -100 * self.bias))


def scalar_lambda(ratio, m):
    """lambda of the scalar model P_k = S (1 - lambda^(k+1)) / (1 - lambda), whose
    reflected share R_m / P_m = (lambda - lambda^(m+1)) / (1 - lambda^(m+1)) equals
    ``ratio`` at iteration ``m`` (bisection; the share grows with lambda)."""
    if not ratio > 0:
        return 0.0
    lo, hi = 0.0, 0.99999
    share = lambda x: (x - x ** (m + 1)) / (1 - x ** (m + 1))
    if share(hi) <= ratio:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if share(mid) < ratio else (lo, mid)
    return 0.5 * (lo + hi)


def verdict(power, reflected, start):
    """The :class:`Verdict` of one window's per-iteration totals (numpy) whose first
    iteration is iteration ``start`` of the chains, or None where there are too few
    iterations (fewer than 4) or no power.

    Two estimates of the average's bias, the larger counts: the scalar model (the
    chains' reflected share of their power gives lambda; the average misses the mean of
    lambda^(m+1) over the window), and the measured growth between the halves of the
    window (when significant, z > GROWTH_Z), which with q = lambda^(n/2) means a bias of
    Delta (1 + q) / (2 (1 - q))."""
    n = len(power)
    mean = float(np.mean(power)) if n else 0.0
    if n < 4 or not mean > 0:
        return None
    h = n // 2
    first, second = power[:h], power[n - h:]
    batches = min(4, h)
    b1 = np.array([b.mean() for b in np.array_split(first, batches)])
    b2 = np.array([b.mean() for b in np.array_split(second, batches)])
    spread = 0.5 * (np.var(b1, ddof=1) + np.var(b2, ddof=1))
    se = float(np.sqrt(spread * 2.0 / batches))
    growth = float(second.mean() - first.mean()) / mean
    z = growth * mean / se if se > 0 else (np.inf if growth > 0 else 0.0)
    lam = scalar_lambda(float(np.mean(reflected)) / mean, start + n // 2)
    m = start + np.arange(n)
    model = float(np.mean(lam ** (m + 1.0)))
    q = lam ** h
    measured = growth * (1.0 + q) / (2.0 * (1.0 - q)) if z > GROWTH_Z and q < 1 else 0.0
    return Verdict(growth, float(z), lam, -max(model, measured), n, int(start))
