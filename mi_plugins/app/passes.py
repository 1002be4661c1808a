"""Rendering in passes: progress reporting, and Ctrl-C keeps the finished passes.

Works with every integrator: pass k renders ``spp_k`` samples with its own seed,
and the image is the sample-weighted average of the finished passes (for a
progressive integrator of this package each pass is an independent run).

The package's integrators (their ``progress`` is a :class:`mi_plugins.render.progress.Progress`)
report every finished step: the progress bar counts steps (iterations of
``stochastic_ray`` and ``ray_bundle``), and Ctrl-C inside a pass keeps the steps of
that pass finished so far, weighted by the fraction of the pass's averaged iterations
they make up.
"""
import signal
import threading
import time
from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from mi_plugins.render.pass_seeds import SEED_STRIDE, check_seed, scene_spp, split_spp
from mi_plugins.render.progress import Progress


@dataclass
class PassResult:
    image: np.ndarray       # (H, W, C) float32, average of the finished passes
    spp_done: int
    passes_done: int
    passes: int
    seconds: float
    interrupted: bool
    #: iterative integrators: iterations finished (all passes) and planned
    iterations_done: int = 0
    iterations: int = 0
    #: share (0..1) of the interrupted pass's averaged iterations that the image holds
    partial_pass: float = 0.0

    @property
    def empty(self):
        """True when no finished work made it into the image (it is then all zeros)."""
        return self.passes_done == 0 and self.partial_pass == 0.0


def _iterative(integrator):
    """True for the package's integrators, which report their steps."""
    return isinstance(getattr(integrator, "progress", None), Progress)


def render_in_passes(scene, spp=None, passes=8, seed=0, progress_bar=False, callback=None, sensor=0):
    """Render ``scene`` (from its sensor ``sensor``: an index or a sensor) with ``spp``
    samples split into ``passes`` passes.

    ``callback(passes_done, passes)`` is called after each pass; ``progress_bar`` shows a tqdm
    bar when tqdm is installed (counting iterations for iterative integrators, passes
    otherwise). A KeyboardInterrupt stops rendering and returns the finished passes
    (``interrupted=True``), plus, for an iterative integrator, the finished iterations of
    the interrupted pass. Invalid ``spp``, ``passes`` or ``seed`` raise ValueError before
    any rendering.
    """
    if int(passes) < 1:
        raise ValueError("passes = %d; valid range: 1 or more" % passes)
    source = "the scene sampler's sample_count" if spp is None else "spp"
    spp = scene_spp(scene) if spp is None else int(spp)
    if spp < 1:  # Mitsuba dies with SIGFPE on 0 samples per pixel
        raise ValueError("samples per pixel: %s = %d; valid range: 1 or more" % (source, spp))
    parts = split_spp(spp, passes)
    check_seed(seed, len(parts))
    integrator = scene.integrator()
    iterative = _iterative(integrator)
    planned = sum(integrator.iteration_count(part) for part in parts) if iterative else 0
    bar = _progress_bar(planned if iterative else len(parts), "iteration" if iterative else "pass") \
        if progress_bar else None
    accum, weight, done, interrupted, iterations_done, partial = None, 0.0, 0, False, 0, 0.0
    t0 = time.perf_counter()
    if iterative:
        def on_iteration(finished, total):
            if bar is not None:
                bar.update(1)
        integrator.progress_callback = on_iteration
    sigint = _SigintRecorder()
    try:
        for k, part in enumerate(parts):
            try:
                img = np.array(mi.render(scene, sensor=sensor, spp=part, seed=int(seed) * SEED_STRIDE + k),
                               dtype=np.float64)
            except Exception:
                # Mitsuba's C++ integrators catch SIGINT themselves, cancel the render and
                # re-raise the signal; the cancelled render may surface as an exception.
                if sigint.received:
                    raise KeyboardInterrupt
                raise
            share = 1.0
            if iterative:
                progress = integrator.progress
                iterations_done += progress.done
                share = progress.averaged_fraction
            if share > 0:
                accum = img * part * share if accum is None else accum + img * part * share
                weight += part * share
            if iterative and progress.interrupted:
                partial = share
                raise KeyboardInterrupt
            done += 1
            if bar is not None and not iterative:
                bar.update(1)
            if callback is not None:
                callback(done, len(parts))
    except KeyboardInterrupt:
        interrupted = True
    except Exception:
        if bar is not None:
            bar.leave = False  # the error message alone, not a stalled bar above it
        raise
    finally:
        sigint.restore()
        if bar is not None:
            bar.close()
        if iterative:
            integrator.progress_callback = None
    if accum is None:
        film = (scene.sensors()[sensor] if isinstance(sensor, int) else sensor).film()
        size = film.crop_size()
        accum, weight = np.zeros((size[1], size[0], 3)), 1.0
    return PassResult((accum / weight).astype(np.float32), sum(parts[:done]), done, len(parts),
                      time.perf_counter() - t0, interrupted, iterations_done, planned, partial)


class _SigintRecorder:
    """While rendering, Ctrl-C raises KeyboardInterrupt as usual and is also recorded
    (only in the main thread; elsewhere Python does not allow signal handlers)."""

    def __init__(self):
        self.received, self.installed, self.previous = False, False, None
        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGINT, self._handle)
            self.installed = True

    def _handle(self, signum, frame):
        self.received = True
        raise KeyboardInterrupt

    def restore(self):
        if self.installed:
            signal.signal(signal.SIGINT, self.previous if self.previous is not None else signal.default_int_handler)
            self.installed = False


def _progress_bar(total, unit):
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, unit=unit, desc="rendering", leave=True)
