"""Gradients of the analytic cases: a differentiable integrator against the exact derivatives.

:func:`check_gradient` renders ``runs`` independent seeds of the derivative of the image
w.r.t. a named case parameter with Mitsuba's automatic differentiation and tests them
with the statistics of :func:`mi_plugins.verify.analytic.harness.compare` against
``case.expected_derivative(name, max_depth)``:

- **forward** mode: one gradient-enabled variable theta (Color3f, zero) is added to the
  parameter on every surface (``case.derivative_keys``), ``dr.set_grad(theta, 1)``,
  ``dr.forward_to(image)``: each run gives a derivative image, tested like a rendered
  image (mean, structure, pixels);
- **reverse** mode: the loss is the image mean, ``dr.backward(loss)``; the sum of the
  channels of theta's gradient is the derivative of the loss w.r.t. the parameter moved
  on every surface and channel, i.e. the mean of the exact derivative image. Each run gives
  one value (its single pixel test runs at the mean test's level).

>>> res = check_gradient(analytic.furnace(), 'prb', 'albedo', spp=64, runs=16, mode='reverse')
>>> res.passed, res.mean, res.expected_mean, res.z
"""
import time
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base.errors import root_cause
from mi_plugins.verify.analytic import harness, stats

MODES = ("forward", "reverse")


@dataclass(repr=False)
class GradientResult(harness.CheckResult):
    """A :class:`~mi_plugins.verify.analytic.harness.CheckResult` of a derivative: ``parameter``
    (the case's name for it), ``mode`` ('forward' or 'reverse'), ``keys`` (the scene
    parameters moved together)."""
    parameter: str = ""
    mode: str = "forward"
    keys: list = field(default_factory=list)

    def __repr__(self):
        status, rest = harness.CheckResult.__repr__(self).split(" ", 1)
        return "%s dL/d%s (%s mode) %s" % (status, self.parameter, self.mode, rest.lstrip())


def render_gradient_runs(scene, keys, spp, runs, seed, mode="forward"):
    """Derivatives of ``runs`` independent renders of ``scene`` w.r.t. the scene parameters
    ``keys`` moved together, numpy float64: (runs, H, W, 3) images in forward mode, (runs, 1,
    1, 1) derivatives of the image mean in reverse mode. The parameters (RGB values, Color3f)
    are restored after."""
    if mode not in MODES:
        raise ValueError("mode=%r: must be one of %s" % (mode, ", ".join(MODES)))
    params = mi.traverse(scene)
    originals = {key: dr.detach(params[key]) for key in keys}
    out = []
    try:
        for r in range(int(runs)):
            theta = dr.zeros(mi.Color3f, 1)
            dr.enable_grad(theta)
            for key in keys:
                params[key] = originals[key] + theta
            params.update()
            image = mi.render(scene, params, spp=int(spp), seed=harness.run_seed(seed, r))
            if mode == "forward":
                dr.set_grad(theta, 1.0)
                out.append(np.array(dr.forward_to(image), dtype=np.float64))
            else:
                dr.backward(dr.mean(image, axis=None))
                out.append(np.full((1, 1, 1), np.sum(np.array(dr.grad(theta), dtype=np.float64))))
            del image, theta
    except RuntimeError as e:
        cause = root_cause(e)  # mi.render wraps an integrator's exception in a generic one
        if cause is e:
            raise
        raise type(cause)(*cause.args) from e
    finally:
        for key in keys:
            params[key] = originals[key]
        params.update()
    return np.stack(out)


def check_gradient(case, integrator, name, spp=64, runs=16, seed=0, mode="forward", z_bound=harness.Z_BOUND,
                   bias=None, max_depth=None, sampler=None, pixel_alpha=harness.PIXEL_ALPHA,
                   max_pixel_failure_fraction=0.01, expected=None):
    """Test the derivative of ``case``'s image w.r.t. its parameter ``name`` (e.g. 'albedo',
    the same on every surface) rendered by a differentiable ``integrator`` (plugin name or
    dict; Mitsuba's ``prb``, ``prb_basic``, ``prbvolpath`` (reverse mode only),
    ``direct_projective``) against ``case.expected_derivative(name, max_depth)``.

    ``mode``: 'forward' or 'reverse'. ``max_depth``: as in :func:`harness.check` (default: the
    integrator's own). ``bias``: known bounded absolute bias (default: the case's for this
    derivative). ``expected``: replaces the exact derivative image (H, W, 3) (tests of the
    test). Returns a :class:`GradientResult`; ValueError for a name without a closed form or
    a parameter the scene's plugins do not expose.
    """
    if mode not in MODES:
        raise ValueError("mode=%r: must be one of %s" % (mode, ", ".join(MODES)))
    spec = case.derivative(name)
    bias = spec.bias if bias is None else float(bias)
    d, label = harness.prepare_check("check_gradient", case, integrator, spp, runs, bias, z_bound, sampler)
    depth = harness.effective_max_depth(d) if max_depth is None else int(max_depth)
    result = GradientResult(case=case.name, integrator=label, spp=int(spp), runs=int(runs), bias=bias,
                            max_depth=depth, parameter=name, mode=mode)
    reason = case.not_applicable(d)
    if reason:
        result.applicable, result.reason = False, reason
        return result
    exact = case.expected_derivative(name, depth) if expected is None else np.asarray(expected, dtype=np.float64)
    scene = case.scene(d, sampler)
    result.keys = case.derivative_keys(name, mi.traverse(scene))
    t0 = time.perf_counter()
    values = render_gradient_runs(scene, result.keys, spp, runs, seed, mode)
    result.seconds = time.perf_counter() - t0
    if mode == "reverse":
        # one value per run: its pixel test at the level of the mean test
        exact = np.full((1, 1, 1), float(exact.mean()))
        pixel_alpha = min(pixel_alpha, stats.normal_two_sided_p(z_bound))
    return harness.record(result, harness.compare(values, exact, z_bound, bias, pixel_alpha,
                                                  max_pixel_failure_fraction))


def closed_forms(cases):
    """[(case, parameter, scene parameter key, formula)] of the derivatives of ``cases``
    ({name: factory}), for reports and the README."""
    rows = []
    for case_name, factory in cases.items():
        case = factory(resolution=1)
        for name, spec in case.derivatives.items():
            rows.append((case_name, name, "<surface>." + spec.key, spec.formula))
    return rows


__all__ = ["GradientResult", "check_gradient", "render_gradient_runs", "closed_forms", "MODES"]
