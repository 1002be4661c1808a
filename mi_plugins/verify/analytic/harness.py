"""Statistical verification of an integrator against an analytic case.

:func:`check` renders ``runs`` independent seeds, estimates standard errors from
the spread between runs (robust for integrators whose pixels are correlated,
such as light tracers and finite-element methods), and passes only if

1. **mean**: the image mean lies within the z bound of the exact mean (Student-t
   bound with ``runs - 1`` degrees of freedom at the same two-sided level as
   ``z_bound`` under a normal law), plus an explicit known ``bias``;
2. **structure**: where the exact image is not constant, each run's image is
   regressed on the exact image's structure (its deviation from its mean); the
   slope must be 1 within the same Student-t bound (a mirrored image, a wrong
   contrast or any misplaced radiance lowers or raises it). Like the mean, the
   slope is one number per run, so its test is exact whatever the correlation
   between pixels;
3. **pixels**: per-pixel t-tests at a Šidák-corrected family-wise level
   ``pixel_alpha`` fail for at most ``max_pixel_failure_fraction`` of the pixel
   channels (a backstop for localised errors). With few runs a pixel's sample
   variance is unreliable (zero when, by chance, all runs agree, as happens with
   Russian roulette), so the tests are *moderated* (empirical Bayes, as in limma):
   each pixel variance is shrunk towards the channel's pooled variance with
   ``PRIOR_DF`` prior degrees of freedom;
4. no image contains NaN or infinite values.

Absolute differences up to ``FLOAT_TOLERANCE`` * max(1, |exact|) are accepted
as float32 rounding (it matters only for deterministic pixels).

Power and false failures: every comparison reports its ``tolerance`` (the largest
deviation of the mean it accepts: t bound x SE + bias), ``relative_tolerance`` (the
same relative to the exact mean: the smallest relative bias the check detects with
probability 1/2) and ``false_failure`` (an upper bound of the probability that a
correct integrator fails it: the two-sided tail of the mean and structure tests plus,
by Markov's inequality, ``pixel_alpha`` divided by the number of pixel failures that
fail the check, whatever the correlation between pixels).
"""
import math
import time
import warnings
from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from mi_plugins.verify.analytic import stats

FLOAT_TOLERANCE = 2e-5
PRIOR_DF = 8
#: default z bound of the mean and structure tests: two-sided 6.8e-6 under a normal law
Z_BOUND = 4.5
#: default family-wise level of the per-pixel tests of one comparison
PIXEL_ALPHA = 1e-4
#: the structure test runs where the exact image's RMS deviation from its mean exceeds
#: this fraction of the mean (below it the exact image is constant up to rounding)
STRUCTURE_MIN = 1e-4
#: callables called with the statistics of every comparison (the test suite records them)
OBSERVERS = []


@dataclass
class CheckResult:
    case: str
    integrator: str
    spp: int
    runs: int
    applicable: bool = True
    reason: str = ""
    passed: bool = False
    mean: float = float("nan")
    expected_mean: float = float("nan")
    se: float = float("nan")
    z: float = float("nan")
    z_limit: float = float("nan")
    bias: float = 0.0
    #: the largest deviation of the mean the check accepts (z_limit x SE + bias + rounding)
    tolerance: float = float("nan")
    #: tolerance / |exact mean|: the smallest relative bias the check detects (with probability 1/2)
    relative_tolerance: float = float("nan")
    #: structure test (NaN where the exact image is constant): slope, its SE and accepted |slope - 1|
    slope: float = float("nan")
    slope_se: float = float("nan")
    slope_tolerance: float = float("nan")
    rmse: float = float("nan")
    pixel_failures: int = 0
    pixel_tests: int = 0
    #: upper bound of the probability that a correct integrator fails this check
    false_failure: float = 0.0
    seconds: float = 0.0
    max_depth: int = -1
    failures: list = field(default_factory=list)
    known_failure: str = ""  # a documented finding: reported as XFAIL / XPASS
    image: object = None  # mean image (numpy), not part of the reports

    @property
    def status(self):
        if not self.applicable:
            return "N/A"
        if self.known_failure:
            return "XPASS" if self.passed else "XFAIL"
        return "PASS" if self.passed else "FAIL"

    @property
    def ok(self):
        """True unless this is an unexpected failure."""
        return self.status != "FAIL"

    def as_dict(self):
        d = {k: v for k, v in self.__dict__.items() if k != "image"}
        d["status"] = self.status
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}

    def __repr__(self):
        if not self.applicable:
            return "N/A  %s x %s: %s" % (self.case, self.integrator, self.reason)
        text = ("%s %s x %s (spp %d x %d runs, max_depth %d): exact %.5g, measured %.5g +- %.2g "
                "(z = %+.2f, limit %.2f, bias %.2g; detects a relative bias of %.2g %%)%s, RMSE %.4g, "
                "%d/%d pixel tests failed, %.2f s"
                % (self.status, self.case, self.integrator, self.spp, self.runs, self.max_depth,
                   self.expected_mean, self.mean, self.se, self.z, self.z_limit, self.bias,
                   100 * self.relative_tolerance,
                   "" if math.isnan(self.slope) else ", structure slope %.4g +- %.2g" % (self.slope, self.slope_se),
                   self.rmse, self.pixel_failures, self.pixel_tests, self.seconds))
        if self.failures:
            text += "\n  - " + "\n  - ".join(self.failures)
        return text


def min_runs(z_bound=Z_BOUND, factor=1.5):
    """The fewest runs whose Student-t bound is at most ``factor`` times ``z_bound``."""
    runs = 2
    while stats.t_quantile_for_z(z_bound, runs - 1) > factor * z_bound:
        runs += 1
    return runs


def integrator_dict(integrator):
    if isinstance(integrator, str):
        return {"type": integrator}
    if not isinstance(integrator, dict) or "type" not in integrator:
        raise ValueError("integrator=%r: must be a plugin name or a Mitsuba dict with a 'type'" % (integrator,))
    return dict(integrator)


def effective_max_depth(d):
    """The max_depth an integrator dict renders with: its own entry, else the plugin's
    default (e.g. 6 for Mitsuba's `prb`, -1 for `path`, `volpath`, `ptracer`)."""
    if "max_depth" in d:
        return int(d["max_depth"])
    try:
        default = getattr(mi.load_dict(dict(d)), "max_depth", -1)
    except Exception:
        default = -1
    return int(default) if default is not None else -1


def integrator_label(d):
    extra = ", ".join("%s=%s" % (k, v) for k, v in d.items() if k != "type")
    return d["type"] + ("(%s)" % extra if extra else "")


def run_seed(seed, r):
    """The render seed of run ``r`` of a check with ``seed``."""
    return (int(seed) * 7919 + int(r)) & 0xFFFFFFFF


def render_runs(scene, spp, runs, seed):
    """Render ``runs`` independent images (numpy, float64) with seeds derived from ``seed``."""
    images = []
    for r in range(runs):
        img = mi.render(scene, spp=spp, seed=run_seed(seed, r))
        images.append(np.array(img, dtype=np.float64))
    return np.stack(images)


def _run_statistic(values, target, tol, z_limit):
    """Mean, SE, z and pass/fail of per-run ``values`` against ``target`` (exact
    statistic), accepting ``tol`` (bias, rounding) plus ``z_limit`` SE."""
    runs = values.shape[0]
    mean = float(values.mean())
    se = float(values.std(ddof=1) / math.sqrt(runs))
    diff = mean - target
    z = diff / se if se > 0 else (0.0 if abs(diff) <= tol else math.copysign(math.inf, diff))
    return mean, se, float(z), abs(diff) <= tol + z_limit * se


def compare(images, exact, z_bound=Z_BOUND, bias=0.0, pixel_alpha=PIXEL_ALPHA,
            max_pixel_failure_fraction=0.01):
    """Statistics of rendered ``images`` (runs, H, W, C) against the exact image (H, W, C).

    Returns a dict with mean, expected_mean, se, z, z_limit, tolerance,
    relative_tolerance, slope, slope_se, slope_tolerance (NaN for a constant exact
    image), rmse, pixel_failures, pixel_tests, false_failure, failures (list of
    messages) and passed. Every registered observer (``OBSERVERS``) is called with it.
    """
    runs = images.shape[0]
    if runs < 2:
        raise ValueError("runs=%d: at least 2 independent runs are needed to estimate errors" % runs)
    if images.shape[1:] != exact.shape:
        raise ValueError("rendered images have shape %s, the exact image %s" % (images.shape[1:], exact.shape))
    failures = []
    finite = np.all(np.isfinite(images))
    if not finite:
        failures.append("%d non-finite pixel values (NaN/inf)" % int(np.sum(~np.isfinite(images))))
        images = np.where(np.isfinite(images), images, 0.0)
    df = runs - 1
    z_limit = stats.t_quantile_for_z(z_bound, df)
    level = stats.normal_two_sided_p(z_bound)
    float_tol = FLOAT_TOLERANCE * max(1.0, float(np.max(np.abs(exact))))

    # 1. the image mean
    expected_mean = float(exact.mean())
    tol = bias + float_tol
    mean, se, z, ok = _run_statistic(images.mean(axis=(1, 2, 3)), expected_mean, tol, z_limit)
    if not ok:
        failures.append("image mean %.6g differs from exact %.6g by %.3g > bias %.3g + %.2f SE (SE %.3g, z %.2f)"
                        % (mean, expected_mean, mean - expected_mean, bias, z_limit, se, z))
    tolerance = tol + z_limit * se
    false_failure = level

    # 2. the structure: slope of each run's image on the exact image's deviation from its mean
    structure = exact - expected_mean
    norm = float(np.sum(structure * structure))
    slope = slope_se = slope_z = slope_tolerance = float("nan")
    if norm > (STRUCTURE_MIN * max(abs(expected_mean), 1e-30)) ** 2 * exact.size:
        per_run = np.einsum("rhwc,hwc->r", images, structure) / norm
        # a pixel-wise bias or rounding bounded by tol moves the slope by at most this much
        slope_tol = tol * float(np.sum(np.abs(structure))) / norm
        slope, slope_se, slope_z, ok = _run_statistic(per_run, 1.0, slope_tol, z_limit)
        slope_tolerance = slope_tol + z_limit * slope_se
        false_failure += level
        if not ok:
            failures.append("image structure: slope %.4g on the exact image's structure, not 1 (SE %.3g, z %.2f, "
                            "allowed %.3g): misplaced or wrongly scaled radiance"
                            % (slope, slope_se, slope_z, slope_tolerance))

    # 3. per-pixel moderated t-tests
    pixel_mean = images.mean(axis=0)
    pixel_var = images.var(axis=0, ddof=1)
    pooled_var = pixel_var.reshape(-1, pixel_var.shape[-1]).mean(axis=0)
    moderated_var = (df * pixel_var + PRIOR_DF * pooled_var) / (df + PRIOR_DF)
    pixel_se = np.sqrt(moderated_var / runs)
    excess = np.abs(pixel_mean - exact) - bias - FLOAT_TOLERANCE * np.maximum(1.0, np.abs(exact))
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(excess <= 0, 0.0, np.where(pixel_se > 0, excess / pixel_se, np.inf))
    p = stats.t_two_sided_p(np.minimum(t, 1e6), df + PRIOR_DF)
    n_tests = int(exact.size)
    pixel_failures = int(np.sum(p < stats.sidak_alpha(pixel_alpha, n_tests)))
    allowed = int(math.floor(max_pixel_failure_fraction * n_tests))
    if pixel_failures > allowed:
        failures.append("%d of %d per-pixel tests failed (Sidak-corrected level %.3g; allowed %d)"
                        % (pixel_failures, n_tests, pixel_alpha, allowed))
    # Markov: E[failures] <= pixel_alpha, so P(failures > allowed) <= pixel_alpha / (allowed + 1)
    false_failure += pixel_alpha / (allowed + 1)

    rmse = float(np.sqrt(np.mean((images - exact[None]) ** 2)))
    out = dict(mean=mean, expected_mean=expected_mean, se=se, z=z, z_limit=z_limit, runs=runs,
               tolerance=tolerance, relative_tolerance=tolerance / max(abs(expected_mean), 1e-30),
               slope=slope, slope_se=slope_se, slope_tolerance=slope_tolerance, rmse=rmse,
               pixel_failures=pixel_failures, pixel_tests=n_tests, false_failure=false_failure,
               failures=failures, passed=not failures, image=pixel_mean)
    for observer in OBSERVERS:
        observer(out)
    return out


def check(case, integrator, spp=64, runs=16, seed=0, z_bound=Z_BOUND, bias=0.0, max_depth=None,
          sampler=None, pixel_alpha=PIXEL_ALPHA, max_pixel_failure_fraction=0.01):
    """Render ``case`` with ``integrator`` ``runs`` times and test it against the exact radiance.

    ``integrator``: plugin name or Mitsuba dict; its ``max_depth`` (or the plugin's default,
    e.g. 6 for `prb`) selects the exact truncated value unless ``max_depth`` is given
    explicitly (to test a deliberately wrong expectation). ``bias``: a known, bounded
    absolute bias (e.g. a discretisation tolerance), added to the bound explicitly.
    ``sampler``: sensor sampler dict. Returns a :class:`CheckResult`; ``result.passed`` is
    the verdict and ``result.relative_tolerance`` the smallest relative bias it detects.
    Warns (``RuntimeWarning``) when ``runs`` is so small that the Student-t bound exceeds
    1.5 times ``z_bound`` (fewer runs at the same total cost test less).
    """
    d, label = prepare_check("check", case, integrator, spp, runs, bias, z_bound, sampler)
    depth = effective_max_depth(d) if max_depth is None else int(max_depth)
    result = CheckResult(case=case.name, integrator=label, spp=int(spp), runs=int(runs), bias=float(bias),
                         max_depth=depth)
    reason = case.not_applicable(d)
    if reason:
        result.applicable, result.reason = False, reason
        return result
    exact = case.expected(depth)
    t0 = time.perf_counter()
    images = render_runs(case.scene(d, sampler), int(spp), int(runs), int(seed))
    result.seconds = time.perf_counter() - t0
    return record(result, compare(images, exact, z_bound, bias, pixel_alpha, max_pixel_failure_fraction))


def prepare_check(caller, case, integrator, spp, runs, bias, z_bound, sampler=None):
    """The arguments every check validates: returns (integrator dict, report label).
    Warns (``RuntimeWarning``, at the caller of ``caller``) when ``runs`` gives little power."""
    d = integrator_dict(integrator)
    label = integrator_label(d)
    if sampler:
        label += " [%s sampler]" % sampler.get("type")
    if int(spp) < 1:
        raise ValueError("spp=%r: must be a positive integer" % (spp,))
    if int(runs) < 2:
        raise ValueError("runs=%r: at least 2 independent runs are needed to estimate errors" % (runs,))
    if bias < 0:
        raise ValueError("bias=%r: must be >= 0" % (bias,))
    t_bound = stats.t_quantile_for_z(z_bound, int(runs) - 1)
    if t_bound > 1.5 * z_bound:
        warnings.warn("%s(%s x %s): runs=%d gives a Student-t bound of %.3g SE (%.1fx the normal %.3g): the "
                      "check has little power; prefer more runs at the same total cost (>= %d)"
                      % (caller, case.name, label, int(runs), t_bound, t_bound / z_bound, z_bound,
                         min_runs(z_bound)), RuntimeWarning, stacklevel=3)
    return d, label


def record(result, comparison):
    """Copy the statistics of :func:`compare` into ``result`` (a CheckResult); returns it."""
    for key, value in comparison.items():
        setattr(result, key, value)
    return result
