"""The package's errors: a scene feature an integrator does not render right
(:class:`Unsupported`, raised before any work), an iteration that would stay biased within
its limit (:class:`NotConverged`), and the innermost message of a chained error
(:func:`root_cause`)."""


class Unsupported(ValueError):
    """A scene feature an integrator does not render right: raised before any work.
    ``integrator``: the plugin refusing; ``feature``: the Mitsuba plugin (or case) name."""

    def __init__(self, integrator, feature, subject, why, instead):
        self.integrator, self.feature = integrator, feature
        super().__init__("%s: %s is not supported: %s; %s" % (integrator, subject, why, instead))


class NotConverged(RuntimeError):
    """An iterative integrator whose average would stay measurably biased within its
    stated limit of iterations: raised instead of returning that image. ``needed``: the
    iterations the measurement predicts (0 where it cannot say)."""

    def __init__(self, integrator, what, needed, limit, instead):
        self.integrator, self.needed, self.limit = integrator, int(needed), int(limit)
        need = "it needs about %d iterations" % needed if needed else "it needs more iterations"
        super().__init__("%s: not converged within max_iterations=%d: %s; %s: raise max_iterations to at least %d, "
                         "or %s" % (integrator, limit, what, need, max(needed, 2 * limit), instead))


def root_cause(error):
    """The innermost exception with a message along the ``__cause__`` chain (a wrapper
    such as Dr.Jit's "error while performing a custom differentiable operation" keeps the
    real error there)."""
    best, seen = error, set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        if str(error).strip():
            best = error
        error = error.__cause__
    return best
