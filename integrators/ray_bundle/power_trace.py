"""Has the iteration converged? Measured from the chains of ``ray_bundle``.

The image averages the iterations after the burn-in. Started from the source term, a
chain's radiance grows toward the solution like P_m = P - c lambda^m (lambda: the share of
the power the scene reflects, the paper's contraction ratio, eq. 20), so an average taken
too early is too dark: an albedo-1 room of ``separable`` BSDFs with ``directional_area``
emitters gives 0.110 instead of 0.483 at the default 16 iterations. :class:`PowerTrace`
records every averaged iteration's total power of all chains, sum over lanes of area x
luminance of L (and of its reflected part R), with one reduction per iteration and no
host read. :func:`verdict` predicts the bias of the average from the reflected share of
the power (a scalar model of the iteration gives lambda) and from the growth of the mean
between the first and the second half of the averaged iterations. The integrator then
extends the burn-in by what the model asks for (up to a cap) or warns with the numbers.
"""
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

#: growth of the mean beyond this many standard errors counts
Z = 3.0
#: a predicted relative bias of the image above this is not converged
TOLERANCE = 0.01
#: the burn-in is extended up to this many times the planned iterations of the render
EXTENSION_CAP = 8


@dataclass
class TraceState:
    values: mi.Float       # per averaged iteration: [sum L, sum R]


class PowerTrace:
    """Per averaged iteration of the current window: the chains' total power."""

    def __init__(self, layout, capacity):
        self.layout, self.capacity = layout, max(int(capacity), 1)
        self.state = TraceState(dr.zeros(mi.Float, 2 * self.capacity))
        dr.make_opaque(self.state.values)
        side, tri, _ = layout.lane_parts()
        self.area = dr.gather(mi.Float, layout.table.area, tri)

    def reset(self):
        self.state.values = dr.zeros(mi.Float, 2 * self.capacity)
        dr.make_opaque(self.state.values)

    def record(self, state, index):
        """Add iteration ``index`` (an opaque UInt32 inside the window) of ``state``."""
        total = sum(state.L[1:], state.L[0])
        power = dr.sum(mi.luminance(total) * self.area)
        # (the environment's light reflected once arrives in full from the first iteration:
        # a source of the model, not a part that grows)
        reflected = dr.sum(mi.luminance(state.R - state.sky) * self.area)
        dr.scatter(self.state.values, power, 2 * index)
        dr.scatter(self.state.values, reflected, 2 * index + 1)

    def numpy(self, count):
        v = np.array(self.state.values, dtype=np.float64).reshape(-1, 2)[:count]
        return v[:, 0], v[:, 1]


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
        return -self.bias <= TOLERANCE

    def burn_in_needed(self):
        """Further burn-in iterations (after this window, which becomes burn-in too) for
        the model's bias of a window of the same length to fall to half the tolerance."""
        lam, n = self.reflectance, self.averaged
        if lam <= 0:
            return 1
        lam = min(lam, 0.9995)
        target = 0.5 * TOLERANCE * n * (1 - lam) / (1 - lam ** n)
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
    window (when significant, z > Z), which with q = lambda^(n/2) means a bias of
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
    measured = growth * (1.0 + q) / (2.0 * (1.0 - q)) if z > Z and q < 1 else 0.0
    return Verdict(growth, float(z), lam, -max(model, measured), n, int(start))
