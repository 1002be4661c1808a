"""Rendering in passes: progress reporting, and Ctrl-C keeps the finished passes.

Works with every integrator: pass k renders ``spp_k`` samples with its own seed,
and the image is the sample-weighted average of the finished passes (for a
progressive integrator of this package each pass is an independent run).
"""
import time
from dataclasses import dataclass

import mitsuba as mi
import numpy as np


@dataclass
class PassResult:
    image: np.ndarray       # (H, W, C) float32, average of the finished passes
    spp_done: int
    passes_done: int
    passes: int
    seconds: float
    interrupted: bool


def split_spp(spp, passes):
    """Split ``spp`` into at most ``passes`` positive parts that differ by at most one."""
    passes = max(1, min(int(passes), int(spp)))
    base, extra = divmod(int(spp), passes)
    return [base + (1 if k < extra else 0) for k in range(passes)]


def scene_spp(scene):
    return int(scene.sensors()[0].sampler().sample_count())


def render_in_passes(scene, spp=None, passes=8, seed=0, progress_bar=False, callback=None):
    """Render ``scene`` with ``spp`` samples split into ``passes`` passes.

    ``callback(passes_done, passes)`` is called after each pass; ``progress_bar`` shows a tqdm
    bar when tqdm is installed. A KeyboardInterrupt stops rendering and returns the finished
    passes (``interrupted=True``).
    """
    spp = scene_spp(scene) if spp is None else int(spp)
    parts = split_spp(spp, passes)
    bar = None
    if progress_bar:
        try:
            from tqdm import tqdm
            bar = tqdm(total=len(parts), unit="pass", desc="rendering", leave=True)
        except ImportError:
            bar = None
    accum, done_spp, done, interrupted = None, 0, 0, False
    t0 = time.perf_counter()
    try:
        for k, part in enumerate(parts):
            img = np.array(mi.render(scene, spp=part, seed=int(seed) * 100003 + k), dtype=np.float64)
            accum = img * part if accum is None else accum + img * part
            done_spp += part
            done += 1
            if bar is not None:
                bar.update(1)
            if callback is not None:
                callback(done, len(parts))
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if bar is not None:
            bar.close()
    if accum is None:
        film = scene.sensors()[0].film()
        size = film.crop_size()
        accum, done_spp = np.zeros((size[1], size[0], 3)), 1
    return PassResult((accum / done_spp).astype(np.float32), done_spp if done else 0, done, len(parts),
                      time.perf_counter() - t0, interrupted)
