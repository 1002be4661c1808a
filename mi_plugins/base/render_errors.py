"""The package's errors reach a caller of ``mi.render`` as they were raised.

``mi.render`` runs the integrator's ``render()`` inside ``drjit.custom``, which turns every
exception into ``RuntimeError: drjit.custom(<mitsuba.python.util._RenderOp>): error while
performing a custom differentiable operation. (see above)`` and chains the real one as its
``__cause__``: a refusal's message (the plugin, the feature, what to use instead) would
sit one link down. :func:`install` wraps ``mitsuba.render`` (once per process) so that an
exception raised by one of the package's integrators reaches the caller as itself, its
traceback kept; every other exception, and every result, passes through unchanged.
"""
import functools
import inspect

import mitsuba as mi

#: the start of the message drjit.custom gives the exception it wraps
WRAPPER = "drjit.custom("


def ours(integrator):
    """Whether ``integrator`` is one of the package's plugins."""
    return type(integrator).__module__.startswith("mi_plugins.")


def unwrapped(error, integrator):
    """The exception of the package's ``integrator`` that ``error`` (raised by ``mi.render``)
    wraps, or None where ``error`` is not such a wrapper."""
    if not (isinstance(error, RuntimeError) and str(error).startswith(WRAPPER) and ours(integrator)):
        return None
    return error.__cause__


def _integrator_of(signature, args, kwargs):
    bound = signature.bind_partial(*args, **kwargs)
    integrator = bound.arguments.get("integrator")
    scene = bound.arguments.get("scene")
    if integrator is None and isinstance(scene, mi.Scene):
        integrator = scene.integrator()
    return integrator


def install():
    """Wrap ``mitsuba.render`` (see the module docstring); a second call does nothing."""
    render = mi.render
    if getattr(render, "_mi_plugins_unwraps", False):
        return
    signature = inspect.signature(render)

    @functools.wraps(render)
    def wrapper(*args, **kwargs):
        try:
            return render(*args, **kwargs)
        except RuntimeError as error:
            cause = unwrapped(error, _integrator_of(signature, args, kwargs))
            if cause is None:
                raise
        raise cause.with_traceback(cause.__traceback__)

    wrapper._mi_plugins_unwraps = True
    mi.render = wrapper
