"""The integrator contract: what every integrator of the package shares.

- :mod:`.core`: ``CoreIntegrator``, which owns the sensor, film, samples per pixel and the
  step loop with commit and rollback (``run_steps``); a plugin implements
  ``render_frame(frame)`` and ``check_scene``; :mod:`.frame`: ``Frame``, the blocks one
  render splats into; :mod:`.progress`: the steps of an iterative render and their burn-in;
- :mod:`.camera`: camera samples and rays; :mod:`.handoff`: the light behind delta and
  null lobes, continued by Mitsuba's ``volpath``; :mod:`.burn_in`: the one burn-in model of
  both stochastic-iteration integrators; :mod:`.checks`: what the integrators refuse.

Rule: imports :mod:`mi_plugins.base`, :mod:`mi_plugins.light` and :mod:`mi_plugins.patches` only.
"""
