"""A render split into passes: the samples per pixel of each pass and its seed, the same
for :func:`mi_plugins.app.passes.render_in_passes` (one process) and the tasks of a
distributed render, so that both make the same image."""


#: pass k of a render with seed s uses Mitsuba seed s * SEED_STRIDE + k (a 32-bit integer)
SEED_STRIDE = 100003


def check_seed(seed, passes):
    """ValueError unless every pass seed of ``passes`` passes fits Mitsuba's 32-bit seed."""
    top = (2 ** 32 - int(passes)) // SEED_STRIDE
    if not 0 <= int(seed) <= top:
        raise ValueError("seed=%d is out of range; valid range: 0 .. %d (with %d passes)" % (seed, top, passes))


def split_spp(spp, passes):
    """Split ``spp`` into at most ``passes`` positive parts that differ by at most one."""
    passes = max(1, min(int(passes), int(spp)))
    base, extra = divmod(int(spp), passes)
    return [base + (1 if k < extra else 0) for k in range(passes)]


def scene_spp(scene):
    return int(scene.sensors()[0].sampler().sample_count())
