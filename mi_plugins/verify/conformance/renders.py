"""Render a cell's runs: one image per seed, the view-independent solutions shared
between the display modes of one solve.

The display modes of a finite-element integrator (``'smooth'``, ``'patches'``,
``'baked'``) show one solution in three ways. A cell of one display mode renders with the
solutions another display mode's cell of the same scene and settings has already solved
in this process, seed by seed (kept here with their scene object, the last family's
only), so that the suites check every display mode for the price of one solve per run
(a display mode rendered again solves again: repeated renders stay independent);
the comparison is the same as if the cell had solved itself (the same seed gives the
same solution, up to the order of float additions). A solve is never shared between
seeds.
"""
import gc
import time
import warnings

import mitsuba as mi
import numpy as np


#: the last shared family: [family key, its scene object, {seed: Solution}, the display
#: modes that rendered them]
_SHARED = [None, None, {}, set()]


def _family(scene_dict, integrator_dict):
    """The key of the solutions a render of ``integrator_dict`` in a display mode may share:
    the scene dict's text and every integrator parameter but the display mode; None for a
    render that shows no stored solution, or a scene dict whose text names objects by
    their address (two such dicts may hold different content)."""
    if integrator_dict.get("display", "gather") == "gather":
        return None
    text = repr(scene_dict)
    if " at 0x" in text or "object at" in text:
        return None
    return text, tuple(sorted((k, repr(v)) for k, v in integrator_dict.items() if k != "display"))


def render_seeds(scene_dict, integrator_dict, spp, seeds):
    """Load the scene and the integrator (dicts) and render one image per seed: (images
    (runs, H, W, C) float64, seconds of each render, warning messages).

    The integrator is loaded on its own and passed to ``mi.render`` rather than put into
    the scene: an integrator that keeps the scene would otherwise form a reference cycle
    through C++ that Python cannot collect, and every leaked scene slows down all later
    renders of the process (Dr.Jit traces every live plugin instance). A display mode's
    render of the last family's scene renders that scene object itself with its kept
    solutions (Mitsuba may merge a scene's meshes in another order on every load, and a
    solution serves the scene content it was solved for)."""
    with warnings.catch_warnings(record=True) as records:
        warnings.simplefilter("always")
        family = _family(scene_dict, integrator_dict)
        display = integrator_dict.get("display")
        shared = family is not None and family == _SHARED[0] and display not in _SHARED[3]
        scene = _SHARED[1] if shared else mi.load_dict(dict(scene_dict))
        integ = mi.load_dict(dict(integrator_dict))
        if not hasattr(integ, "use_solution"):
            family = None
        elif family is not None:
            if not shared:
                _SHARED[:] = [family, scene, {}, set()]
            _SHARED[3].add(display)
        images, times = [], []
        for s in seeds:
            if family is not None:
                integ.use_solution(_SHARED[2].get(int(s)))
            t0 = time.perf_counter()
            images.append(np.array(mi.render(scene, integrator=integ, spp=int(spp), seed=s), dtype=np.float64))
            times.append(time.perf_counter() - t0)
            if family is not None and integ.last_solution is not None:
                _SHARED[2][int(s)] = integ.last_solution
        caught = sorted({str(w.message) for w in records})
    del scene, integ
    gc.collect()    # free the scene now: Dr.Jit traces every live plugin instance in later renders
    return np.stack(images), times, caught


def forget():
    """Drop the kept scene and solutions."""
    _SHARED[:] = [None, None, {}, set()]
