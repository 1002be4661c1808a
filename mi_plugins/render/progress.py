"""Progress of the package's iterative integrators, and early stopping.

Every integrator of the package has ``integrator.progress`` (a :class:`Progress`: what
the last or current render has done) and ``integrator.progress_callback`` (None, or
``f(done, total)`` called after every step; returning ``False`` or raising
``KeyboardInterrupt`` stops the render early, and so does Ctrl-C during a step). The
image of a stopped render is made of the finished steps. ``integrator.iteration_count(spp)``
is the number of steps a render with ``spp`` runs (what a progress bar counts).
:mod:`mi_plugins.app.passes` reads these to weight an interrupted pass.
"""
from dataclasses import dataclass


@dataclass
class Progress:
    """The state of one render: ``done`` of ``total`` steps (iterations, then the steps of
    a second stage such as a final gathering), of which ``averaged`` count towards the
    image out of ``planned_averaged``; ``interrupted`` when it stopped early."""
    total: int = 0
    burn_in: int = 0
    done: int = 0
    second_stage: int = 0
    interrupted: bool = False
    planned_averaged: int = 0

    @property
    def iterations(self):
        return self.done - self.second_stage

    @property
    def averaged(self):
        return max(0, self.iterations - self.burn_in)

    @property
    def averaged_fraction(self):
        """Averaged iterations finished / planned (what an interrupted pass is weighted by)."""
        return self.averaged / max(1, self.planned_averaged)


class Steps:
    """Drives one render's steps for ``owner`` (an integrator with ``progress`` and
    ``progress_callback``): ``for it in steps.iterations(): ...`` runs ``iterations``
    steps after which ``burn_in`` are averaged; ``steps.second_stage(count)`` runs steps
    after them (always at least one). A KeyboardInterrupt raised inside a step must be
    caught by the caller, which then calls :meth:`stop`."""

    def __init__(self, owner, iterations, burn_in, total=None):
        self.owner = owner
        self.state = Progress(total=int(iterations if total is None else total), burn_in=int(burn_in),
                              planned_averaged=max(0, int(iterations) - int(burn_in)))
        self.count = int(iterations)
        owner.progress = self.state

    def iterations(self):
        it = 0
        while it < self.count:        # (extend may raise the count during the loop)
            yield it
            it += 1
            self.state.done += 1
            if not self._report():
                return

    def extend(self, count, restart_average=True):
        """Run ``count`` more iterations; with ``restart_average`` the ones done so far
        become burn-in (their image is discarded by the caller)."""
        if restart_average:
            self.state.burn_in = self.count
        self.count += int(count)
        self.state.total += int(count)
        self.state.planned_averaged = self.count - self.state.burn_in

    def lengthen_burn_in(self, burn_in):
        """Make the burn-in ``burn_in`` iterations long, the averaged iterations after it
        as many as planned (the total grows by the difference)."""
        averaged = self.count - self.state.burn_in
        self.extend(int(burn_in) - self.state.burn_in, restart_average=False)
        self.state.burn_in = int(burn_in)
        self.state.planned_averaged = averaged

    def next_window(self, done, burn_in, window):
        """After ``done`` iterations, run ``burn_in`` more of burn-in and a new averaged
        window of ``window`` (``iterations()`` counts from 0 again): everything before the
        window is burn-in."""
        self.count = int(burn_in) + int(window)
        self.state.total += int(burn_in) + int(window)
        self.state.burn_in = int(done) + int(burn_in)

    def second_stage(self, count):
        for k in range(count):
            yield k
            self.state.done += 1
            self.state.second_stage += 1
            if not self._report():
                return

    def _report(self):
        callback = getattr(self.owner, "progress_callback", None)
        if callback is not None:
            try:
                if callback(self.state.done, self.state.total) is False:
                    self.stop()
                    return False
            except KeyboardInterrupt:
                self.stop()
                return False
        return True

    def stop(self):
        self.state.interrupted = True
