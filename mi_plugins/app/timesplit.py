"""How a view-independent solution spends a number of seconds: one solve, then the camera
samples of its display.

The solve gets ``SOLVE_SHARE`` of the seconds (measured on the demo's Cornell box:
docs/solutions.md, "The demo: budgets and a walkthrough"), sized by a line measured on this machine
(:class:`SolveRate`: two solves on fresh scene objects, the kernels compiled first on
another, and corrected by every solve it sizes: :meth:`SolveRate.observe`); the display
gets the camera samples that fit in the rest, from pilot renders (:func:`pilot`), and at
least ``DISPLAY_FLOOR`` of its share where the solve overran (a machine busier than when
the rate was measured: the total then exceeds the seconds, and the reported time says
so). Every second is counted: the solve, the pilots, the display.
"""
import time

import mitsuba as mi
import numpy as np

#: the parameter that sizes each integrator's solve, and its smallest value
SIZE = {"qmc_lighttrace": ("samples", 50000), "ray_bundle": ("iterations", 16)}
#: the two solve sizes a SolveRate is measured at
RATE_SIZES = {"qmc_lighttrace": (200000, 800000), "ray_bundle": (16, 32)}
#: the solve's share of the seconds: one view (the demo's rows), a walkthrough's frames
SOLVE_SHARE = {"view": 0.8, "walk": 0.3}
#: the least part of its share the display gets when the solve overran
DISPLAY_FLOOR = 0.5
#: a pilot render is long enough to time at this share of the display's seconds (or PILOT_MOST spp)
PILOT_SHARE = 0.05
PILOT_MOST = 256
#: the camera-sample counts a display is given: 2^k, 3, 5 and 7 x 2^k, at most 1.25x apart
#: (a display splits a count into passes by its largest divisor that fits in memory: a
#: large prime count would be that many passes)
SPP_STEPS = sorted({m << k for k in range(15) for m in (1, 3, 5, 7) if m << k <= 1 << 14})


class SolveRate:
    """Seconds of a solve of ``integrator`` (a plugin dict) on a fresh scene object:
    ``fixed + per_unit x size``, size the integrator's ``SIZE`` parameter."""

    def __init__(self, integrator, fixed, per_unit):
        if integrator.get("type") not in SIZE:
            raise ValueError("timesplit: integrator %r has no view-independent solution (valid: %s)"
                             % (integrator.get("type"), ", ".join(sorted(SIZE))))
        self.integrator, self.fixed, self.per_unit = dict(integrator), float(fixed), float(per_unit)
        self.name, self.smallest = SIZE[integrator["type"]]

    @classmethod
    def measure(cls, make_scene, integrator, seed=0):
        """The rate of ``integrator`` on the scenes ``make_scene()`` returns: its kernels
        compiled by a solve and a display render on one scene object, then two solves
        (``RATE_SIZES``) timed on two more."""
        from mi_plugins import solve
        name = SIZE[integrator["type"]][0]
        sizes = RATE_SIZES[integrator["type"]]
        mi.render(make_scene(), integrator=mi.load_dict(dict(integrator, **{name: sizes[0]})), spp=1, seed=seed)
        times = []
        for size in sizes:
            scene, integ = make_scene(), mi.load_dict(dict(integrator, **{name: size}))
            t0 = time.perf_counter()
            solve(scene, integ, seed=seed)
            times.append(time.perf_counter() - t0)
        per_unit = max((times[1] - times[0]) / (sizes[1] - sizes[0]), times[1] / sizes[1] / 4)
        return cls(integrator, max(times[0] - per_unit * sizes[0], 0.0), per_unit)

    def observe(self, size, seconds):
        """Correct the seconds per unit by a solve of ``size`` that took ``seconds``."""
        self.per_unit = max((seconds - self.fixed) / max(int(size), 1), 0.25 * seconds / max(int(size), 1))

    def size(self, seconds):
        """The solve size that takes about ``seconds`` (at least the smallest)."""
        return max(self.smallest, int((seconds - self.fixed) / self.per_unit))

    def sized(self, seconds):
        """The integrator's dict with the solve size of ``seconds``."""
        return dict(self.integrator, **{self.name: self.size(seconds)})


def pilot(render, seconds):
    """``render(spp)`` timed for a render of about ``seconds``: at 1 spp (its one-time
    costs, e.g. the smooth field), then at 1, 4, 16, ... spp until one from 16 on takes
    ``PILOT_SHARE`` of ``seconds``, and that one again: (fixed seconds per render, seconds
    per camera sample, seconds spent, the first render's one-time seconds). The fixed cost
    is the quicker of the 1 and 4 spp renders less their samples, the cost per sample from
    the quicker of the last two (a busy machine's pause in one of them does not count)."""
    t0 = time.perf_counter()
    render(1)
    first = time.perf_counter() - t0
    times, spp = {}, 1
    while True:
        start = time.perf_counter()
        render(spp)
        times[spp] = time.perf_counter() - start
        if spp >= 16 and (times[spp] >= PILOT_SHARE * seconds or spp >= PILOT_MOST):
            start = time.perf_counter()       # timed again: a pause of the machine in one render does not count
            render(spp)
            times[spp] = min(times[spp], time.perf_counter() - start)
            break
        spp *= 4
    small = min(times[1], times[4])
    per_spp = max((times[spp] - small) / (spp - 1), 0.5 * times[spp] / spp)
    return max(small - per_spp, 0.0), per_spp, time.perf_counter() - t0, max(first - times[1], 0.0)


def least_pilot(fixed, per_spp):
    """The seconds of the shortest :func:`pilot` (up to 16 spp, that one twice) at
    ``fixed`` seconds per render and ``per_spp`` per camera sample, one-time costs aside."""
    return 5 * fixed + (1 + 1 + 4 + 16 + 16) * per_spp


def spp_for(seconds, fixed, per_spp, most=1 << 14):
    """Camera samples per pixel of a render that takes at most ``seconds`` (at least 1, at
    most ``most``), rounded down to a count of ``SPP_STEPS``."""
    fit = min(most, max(1.0, (seconds - fixed) / per_spp))
    return max(n for n in SPP_STEPS if n <= fit)


def solve_and_display(scene, rate, seconds, share=SOLVE_SHARE["view"], seed=0):
    """One solve sized to ``share`` x ``seconds`` by ``rate`` (a :class:`SolveRate`), then
    the display with the camera samples that fit in the rest: (image as a numpy array,
    dict of size, spp, solve_seconds, seconds, solves)."""
    from mi_plugins import solve
    t0 = time.perf_counter()
    size = rate.size(share * seconds)
    integ = mi.load_dict(rate.sized(share * seconds))
    solve(scene, integ, seed=seed)
    solved = time.perf_counter() - t0
    rate.observe(size, solved)

    def render(spp):
        return mi.render(scene, integrator=integ, spp=int(spp), seed=seed)
    fixed, per_spp = pilot(render, display_seconds(seconds, time.perf_counter() - t0, share))[:2]
    spp = spp_for(display_seconds(seconds, time.perf_counter() - t0, share), fixed, per_spp)
    image = np.array(render(spp), dtype=np.float64)
    return image, dict(size=size, spp=spp, solve_seconds=solved, seconds=time.perf_counter() - t0,
                       solves=integ.solve_count)


def display_seconds(seconds, spent, share):
    """The display's seconds: what is left of ``seconds`` after ``spent``, at least
    ``DISPLAY_FLOOR`` of its share (1 - ``share``)."""
    return max(seconds - spent, DISPLAY_FLOOR * (1.0 - share) * seconds)
