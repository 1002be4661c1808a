"""Checking integrators against the truth.

- :mod:`.analytic`: scenes whose exact radiance is known, the statistical harness and the
  verification matrix; :mod:`.geometry`: their procedural geometry;
- :mod:`.conformance`: ordinary scenes against Mitsuba's ``path``;
- :mod:`.coverage`: every Mitsuba plugin against every integrator of the package;
- :mod:`.pytest_plugin`: fixtures and an assertion for users' own integrators.

Rule: may import every layer below and the plugins, never :mod:`mi_plugins.distributed` or
:mod:`mi_plugins.app`. (This file imports nothing: the pytest plugin is loaded before any
Mitsuba variant is set.)
"""
