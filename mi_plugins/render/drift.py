"""Is an iterative estimate still drifting? The burn-in check of the package's
stochastic-iteration integrators.

The image of stochastic iteration averages the steps after a burn-in; where the scene
reflects almost everything (albedos near 1), the chains approach their equilibrium so
slowly that a burn-in of a few steps leaves the average far too dark (an albedo-1 room
lit by a weak emitter reads 0.12 instead of 0.48 after 32 steps). :func:`drift` compares
the first and second half of the averaged steps: the image mean of each of
``SEGMENTS`` consecutive segments is measured, and the halves' means are compared
against the segments' noise (a t statistic). A render whose halves
differ by more than ``TOLERANCE`` and ``Z`` standard errors has not converged.
"""
import math

import numpy as np

#: segments the averaged steps are cut into for the check (half of them per half)
SEGMENTS = 8
#: relative difference of the halves' means below which a drift is accepted
TOLERANCE = 0.005
#: and the number of standard errors it must exceed to count (the noise is estimated from
#: few segments: a t statistic with about 4 degrees of freedom, beyond 6 in 0.4 % of
#: converged renders, which then only run longer)
Z = 6.0


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
    """True when the per-segment means ``values`` still drift (see the module docstring)."""
    rel, t = drift(values)
    return abs(rel) > TOLERANCE and abs(t) > Z
