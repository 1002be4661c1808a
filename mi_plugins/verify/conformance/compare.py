"""Two-sample comparison of an integrator's images with a reference integrator's.

Both sides are ``runs`` independent renders (different seeds); every statistic is one
number per run, so the tests are exact whatever the correlation between pixels
(light tracers, finite elements). The project's quantiles are used throughout
(:mod:`mi_plugins.verify.analytic.stats`: Student-t bounds at the same two-sided level as a
normal z bound, Šidák correction).

1. **mean** (the verdict's main test): Welch's two-sample test on the per-run image
   means. The difference must be within ``t x SE + bias + rounding``, with ``t`` the
   Student-t bound at Welch-Satterthwaite's degrees of freedom for the level of
   ``z_bound`` (4.5: two-sided 6.8e-6), SE = sqrt(s_a^2 / R_a + s_b^2 / R_b), ``bias`` an
   explicit, documented bound for methods biased by design (0 otherwise), *relative* to
   the reference's value, and float32 rounding :func:`rounding`. Where both sides are
   deterministic (SE = 0, e.g. a black image or a block of constant sky) only the bias
   and rounding are accepted. The bias covers what the runs cannot resolve only: a
   difference beyond ``t x SE`` (plus rounding) fails whatever the bias allowance, so no
   passing comparison has |z| above the bound.
2. **blocks** (backstop for misplaced radiance: a mirrored image, one dark wall):
   the image is cut into ``block`` x ``block`` pixel blocks; Welch's test on each
   block's and channel's per-run means, at a Šidák-corrected family-wise level
   ``block_alpha``, accepting the relative ``block_bias`` (default: ``bias``; finite
   elements deviate more locally than on average); any failing block fails the
   comparison.
3. no NaN or infinite pixel.

``power``: the relative bias the mean test detects with probability 1/2,
(t x SE + bias x |reference mean| + rounding) / |reference mean| (infinite for a black
reference, |mean| <= ``BLACK``: there only the absolute ``tolerance`` means anything).
"""
import math

import numpy as np

from mi_plugins.verify.analytic import stats
from mi_plugins.verify.analytic.harness import FLOAT_TOLERANCE, Z_BOUND

#: family-wise level of the per-block tests of one comparison
BLOCK_ALPHA = 1e-5
#: pixels per block side
BLOCK = 4
#: relative float32 accumulation error of a pixel averaged over n samples: up to about
#: n x 2^-24 (measured on constant sky with path: 4e-6 at 512 spp, 3.4e-5 at 4096, 1.5e-4
#: at 16384); the references use at most 4096 spp
ACCUMULATION = 4096 * 2.0 ** -24
#: a reference mean at most this large is black (no relative error is defined)
BLACK = 1e-5


def rounding(value):
    """Float32 rounding accepted on a value (numpy-broadcast): the harness's absolute
    ``FLOAT_TOLERANCE`` plus the accumulation error ``ACCUMULATION`` x |value|."""
    return FLOAT_TOLERANCE + ACCUMULATION * np.abs(value)


def welch(a, b):
    """(difference of means, SE, degrees of freedom) of Welch's test on samples ``a``, ``b``
    (numpy arrays whose first axis holds the runs; the rest is kept element-wise)."""
    na, nb = a.shape[0], b.shape[0]
    va, vb = a.var(axis=0, ddof=1) / na, b.var(axis=0, ddof=1) / nb
    diff = a.mean(axis=0) - b.mean(axis=0)
    se2 = va + vb
    with np.errstate(divide="ignore", invalid="ignore"):
        df = se2 * se2 / (va * va / (na - 1) + vb * vb / (nb - 1))
    df = np.where(np.isfinite(df), df, float(na + nb - 2))
    return diff, np.sqrt(se2), df


def block_means(images, block=BLOCK):
    """(runs, blocks_y, blocks_x, C) means over ``block`` x ``block`` pixel blocks (edge
    blocks smaller when the size is not a multiple)."""
    runs, h, w, c = images.shape
    ys = list(range(0, h, block))
    xs = list(range(0, w, block))
    out = np.empty((runs, len(ys), len(xs), c))
    for i, y in enumerate(ys):
        for j, x in enumerate(xs):
            out[:, i, j] = images[:, y:y + block, x:x + block].mean(axis=(1, 2))
    return out


def compare(images, reference, z_bound=Z_BOUND, bias=0.0, block_bias=None, block=BLOCK, block_alpha=BLOCK_ALPHA):
    """Statistics of ``images`` (runs, H, W, C) against ``reference`` images (runs', H, W, C).

    Returns a dict: mean, ref_mean, se, ref_se (of each mean), z, df, limit (the t
    bound), bias, tolerance, power (relative tolerance), block_failures, block_tests,
    worst_block (its |t| and index), rmse (per run, against the reference's mean image),
    false_failure (upper bound: the mean test's level plus ``block_alpha``), failures
    (messages) and passed.
    """
    images = np.asarray(images, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if images.shape[0] < 2 or reference.shape[0] < 2:
        raise ValueError("at least 2 runs per side are needed (got %d and %d)" % (images.shape[0], reference.shape[0]))
    if images.shape[1:] != reference.shape[1:]:
        raise ValueError("images have shape %s, the reference %s" % (images.shape[1:], reference.shape[1:]))
    block_bias = bias if block_bias is None else block_bias
    if not (bias >= 0 and block_bias >= 0):
        raise ValueError("bias=%r, block_bias=%r: must be >= 0" % (bias, block_bias))
    failures = []
    bad = int(np.sum(~np.isfinite(images)))
    if bad:
        failures.append("%d non-finite pixel values (NaN/inf)" % bad)
        images = np.where(np.isfinite(images), images, 0.0)
    level = stats.normal_two_sided_p(z_bound)

    # 1. image means (Welch)
    a, b = images.mean(axis=(1, 2, 3)), reference.mean(axis=(1, 2, 3))
    diff, se, df = (float(v) for v in welch(a, b))
    ref_mean = float(b.mean())
    allowed = bias * abs(ref_mean) + float(rounding(ref_mean))
    limit = stats.t_quantile_for_z(z_bound, df) if se > 0 else float(z_bound)
    tolerance = allowed + limit * se
    if se > 0:
        z = diff / se
    else:
        z = 0.0 if abs(diff) <= allowed else math.copysign(math.inf, diff)
    if not abs(diff) <= tolerance:
        failures.append("image mean %.6g differs from the reference's %.6g by %+.3g > bias %.3g + %.2f SE "
                        "(SE %.3g, z %+.2f, Welch df %.1f)" % (float(a.mean()), ref_mean, diff, bias * abs(ref_mean),
                                                              limit, se, z, df))
    elif se > 0 and abs(diff) > limit * se + float(rounding(ref_mean)):
        # a bias allowance covers what the noise cannot resolve, never a difference the
        # runs measure: beyond the t bound the cell is wrong, whatever the allowance
        failures.append("image mean %.6g differs from the reference's %.6g by %+.3g: within the bias "
                        "allowance %.3g but %.2f SE (z %+.2f, bound %.2f): a measured bias, not noise"
                        % (float(a.mean()), ref_mean, diff, bias * abs(ref_mean), abs(z), z, limit))

    # 2. blocks (Welch per block and channel, Sidak-corrected)
    ba, bb = block_means(images, block), block_means(reference, block)
    bdiff, bse, bdf = welch(ba, bb)
    ref_blocks = np.abs(bb.mean(axis=0))
    excess = np.abs(bdiff) - block_bias * ref_blocks - rounding(ref_blocks)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(excess <= 0, 0.0, np.where(bse > 0, excess / bse, np.inf))
    # (stats.t_two_sided_p takes one df at a time: Welch's df differ per block)
    p = np.array([float(stats.t_two_sided_p(tk, dk)) for tk, dk in
                  zip(np.minimum(t, 1e6).ravel(), np.maximum(bdf, 1.0).ravel())]).reshape(t.shape)
    n_tests = int(t.size)
    fails = p < stats.sidak_alpha(block_alpha, n_tests)
    block_failures = int(np.sum(fails))
    worst = np.unravel_index(int(np.argmax(t)), t.shape)
    if block_failures:
        failures.append("%d of %d block tests failed (%dx%d-pixel blocks, Sidak-corrected level %.0e); worst: "
                        "block (row %d, column %d), channel %d, %.4g vs %.4g (t %.1f)"
                        % (block_failures, n_tests, block, block, block_alpha, worst[0], worst[1], worst[2],
                           float(ba.mean(axis=0)[worst]), float(bb.mean(axis=0)[worst]), float(t[worst])))

    rmse = float(np.sqrt(np.mean((images - reference.mean(axis=0)[None]) ** 2)))
    power = tolerance / abs(ref_mean) if abs(ref_mean) > BLACK else math.inf
    return dict(mean=float(a.mean()), ref_mean=ref_mean, se=float(a.std(ddof=1) / math.sqrt(len(a))),
                ref_se=float(b.std(ddof=1) / math.sqrt(len(b))), diff_se=se, z=float(z), df=df, limit=limit,
                bias=float(bias), block_bias=float(block_bias), tolerance=tolerance, power=power,
                block_failures=block_failures, block_tests=n_tests, rmse=rmse, false_failure=level + block_alpha,
                failures=failures, passed=not failures)
