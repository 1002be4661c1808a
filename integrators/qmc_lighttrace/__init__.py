"""``qmc_lighttrace``: Keller's quasi-Monte Carlo light tracing in the radiosity setting.

- :mod:`.integrator`: the plugin (parameters, render, solution);
- :mod:`.particles`: light paths on a low-discrepancy sequence, their deposits;
- :mod:`.phase`: the particle phase of a render (ranges of paths, adaptive termination,
  refinement); :mod:`.store`: the per-patch tables they fill; :mod:`.checks`: sizes checked
  before any work.
"""
