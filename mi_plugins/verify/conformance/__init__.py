"""Conformance suite: the package's integrators against Mitsuba's ``path`` on ordinary scenes.

Ordinary Mitsuba scenes (written here as Python dicts: meshes of both windings,
``rectangle``/``disk``/``sphere``/``cylinder``/``cube`` shapes, area, point, spot,
directional, constant and envmap lights, textured, glossy, mirror and glass surfaces, a
scene without emitters, a closed box with the light outside) are rendered by
``stochastic_ray``, ``ray_bundle`` and ``qmc_lighttrace`` and by ``path``; each
combination ends as

- **PASS**: the image mean agrees with ``path``'s (Welch's two-sample test over
  independent runs at z 4.5, Student-t bound) and so does every 4 x 4 pixel block
  (Šidák-corrected level 1e-4), within an explicit, documented bias bound where the
  method is biased by design (finite elements);
- **REFUSED**: the integrator raised an error whose message matches the expected pattern;
- **N/A**: the method does not cover the scene by design (documented reason; not run);
- **FAIL**: anything else (a wrong image, a crash, an unexpected refusal).

::

    from mi_plugins import conformance
    conformance.verify()                                   # table; exit status 0 / 1
    conformance.verify(['qmc_lighttrace'], ['glass'], report='reports/')
    r = conformance.run('cornell_mesh', 'ray_bundle')      # -> Result
    r.outcome, r.mean, r.ref_mean, r.z, r.power, r.seconds
    conformance.scenes()                                   # name -> builder(resolution=16)

Details and the current results: ``docs/conformance.md``.
"""
from mi_plugins.verify.conformance import compare, expectations, outcomes, scene_library as _scenes
from .expectations import INTEGRATORS, IntegratorSpec
from .outcomes import FAIL, NA, PASS, REFUSED, NotApplicable, Refused
from .report import format_table, verify
from .runner import Result, clear_references, reference, run, same_seed


def scenes():
    """{name: builder}: ``builder(resolution=16)`` returns the scene dict (no integrator)."""
    return {name: builder for name, (builder, _) in _scenes.SCENES.items()}


def describe():
    """{name: one-line description} of the scenes."""
    return {name: doc for name, (_, doc) in _scenes.SCENES.items()}


__all__ = ["verify", "run", "scenes", "describe", "Result", "reference", "same_seed", "clear_references",
           "INTEGRATORS", "IntegratorSpec", "Refused", "NotApplicable", "PASS", "FAIL", "REFUSED", "NA",
           "format_table", "compare", "expectations", "outcomes"]
