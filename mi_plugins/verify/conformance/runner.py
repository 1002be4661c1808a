"""Run one (scene, integrator) combination: render, compare with ``path``, decide the outcome."""
import gc
import math
import time
from dataclasses import dataclass, field

import numpy as np

from mi_plugins.verify.conformance import compare as comparison
from mi_plugins.verify.conformance import expectations, outcomes, renders
from .scene_library import SCENES

#: references already rendered in this process: {key: (images, seconds)}
_REFERENCES = {}
#: a PASS must detect a relative error of the image mean of this size (its ``power``), and
#: where the reference is black (no relative error exists) accept a mean of at most
#: BLACK_LIMIT; quick runs (half the runs) are a first look: the rule is not applied to them
POWER_LIMIT = 0.05
BLACK_LIMIT = 1e-4


@dataclass
class Result:
    scene: str
    integrator: str
    expected: str = outcomes.PASS          # PASS, REFUSED or N/A
    expected_detail: str = ""              # the refusal pattern or the N/A reason
    outcome: str = outcomes.FAIL
    reason: str = ""                       # N/A reason, or the error of a refusal / crash
    mean: float = float("nan")
    ref_mean: float = float("nan")
    se: float = float("nan")
    ref_se: float = float("nan")
    z: float = float("nan")
    limit: float = float("nan")
    bias: float = 0.0                      # relative bias bound of the mean (documented)
    block_bias: float = 0.0                # relative bias bound of every block
    bias_reason: str = ""
    tolerance: float = float("nan")
    power: float = float("nan")           # relative bias the mean test detects (probability 1/2)
    power_limit: float = POWER_LIMIT      # ... and the most it may be for a PASS
    block_failures: int = 0
    block_tests: int = 0
    rmse: float = float("nan")
    false_failure: float = 0.0
    seconds: float = 0.0                   # the integrator's renders (loading included), wall clock
    ref_seconds: float = 0.0               # the reference's renders (0 when reused), wall clock
    cpu_seconds: float = 0.0               # CPU time of the process for both (all threads)
    runs: int = 0
    spp: int = 0
    ref_runs: int = 0
    ref_spp: int = 0
    ref_depth: int = -1
    params: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    failures: list = field(default_factory=list)

    @property
    def ok(self):
        """True when the outcome is the expected one."""
        return self.outcome == self.expected

    def as_dict(self):
        d = dict(self.__dict__, ok=self.ok)
        d["params"] = {k: v for k, v in self.params.items()}
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}

    def __repr__(self):
        head = "%s %s x %s" % (self.outcome, self.scene, self.integrator)
        if self.expected != self.outcome:
            head += " (expected %s)" % self.expected
        if self.outcome == outcomes.NA or math.isnan(self.mean):     # not run, refused or crashed
            return head + ": " + (self.reason or "; ".join(self.failures))
        text = ("%s: mean %.5g, path %.5g (z %+.2f, limit %.2f, relative bias bound %.2g; detects %.2g %%), "
                "RMSE %.3g, %d/%d block tests failed, %.1f s"
                % (head, self.mean, self.ref_mean, self.z, self.limit, self.bias, 100 * self.power, self.rmse,
                   self.block_failures, self.block_tests, self.seconds))
        if self.failures:
            text += "\n  - " + "\n  - ".join(self.failures)
        return text


def _seeds(seed, runs, stream):
    return [((int(seed) * 7919 + r) * 2654435761 + stream * 40503) & 0xFFFFFFFF for r in range(int(runs))]


def render_runs(scene_dict, integrator, spp, seeds):
    """Load ``scene_dict`` and ``integrator`` (a dict) and render one image per seed:
    (runs, H, W, C) float64 array, seconds, warning messages (:mod:`.renders`)."""
    images, times, caught = renders.render_seeds(scene_dict, integrator, spp, seeds)
    return images, float(sum(times)), caught


def reference(scene, max_depth=-1, resolution=16, spp=None, runs=None, seed=0, quick=False):
    """``runs`` renders of ``scene`` with Mitsuba's ``path`` (cached per process)."""
    spec = expectations.reference_budget(scene, quick)
    spp = int(spp or spec["spp"])
    runs = int(runs or spec["runs"])
    key = (scene, int(max_depth), int(resolution), spp, runs, int(seed))
    if key not in _REFERENCES:
        images, seconds, _ = render_runs(SCENES[scene][0](resolution), {"type": "path", "max_depth": int(max_depth)},
                                         spp, _seeds(seed, runs, 1))
        _REFERENCES[key] = (images, seconds)
        return images, seconds
    return _REFERENCES[key][0], 0.0


def clear_references():
    _REFERENCES.clear()


def run(scene, integrator, runs=None, spp=None, seed=0, quick=False, resolution=16, params=None, expected=None,
        bias=None, z_bound=comparison.Z_BOUND):
    """Run ``integrator`` on ``scene`` and return a :class:`Result`.

    ``integrator``: a name of :data:`expectations.INTEGRATORS` or an
    :class:`expectations.IntegratorSpec` (e.g. a deliberately wrong one, for tests of
    the suite). ``runs``/``spp`` override the budget, ``params`` are merged into the
    integrator dict, ``expected`` (PASS, :class:`outcomes.Refused` or
    :class:`outcomes.NotApplicable`) and ``bias`` override the scene's expectation.
    """
    if scene not in SCENES:
        raise ValueError("unknown scene %r; choose from: %s" % (scene, ", ".join(SCENES)))
    spec = expectations.spec_of(integrator)
    setting = expectations.setting(spec, scene, quick)
    if expected is not None:
        setting.expected = expected
    if bias is not None:
        setting.bias, setting.block_bias, setting.bias_reason = float(bias), float(bias), "given"
    d = dict(setting.params, **(params or {}))
    res = Result(scene=scene, integrator=spec.name, params=d, bias=setting.bias, block_bias=setting.block_bias,
                 bias_reason=setting.bias_reason,
                 expected=outcomes.expected_label(setting.expected))
    if isinstance(setting.expected, outcomes.Refused):
        res.expected_detail = setting.expected.pattern
    if isinstance(setting.expected, outcomes.NotApplicable):
        res.expected_detail = res.reason = setting.expected.reason
        res.outcome = outcomes.NA
        return res
    res.runs, res.spp = int(runs or setting.runs), int(spp or setting.spp)
    res.power_limit = float(spec.power_limit or POWER_LIMIT)
    cpu0 = time.process_time()
    error = None
    try:
        images, res.seconds, res.warnings = render_runs(SCENES[scene][0](resolution), d, res.spp,
                                                        _seeds(seed, res.runs, 0))
    except Exception as exc:    # a refusal, or a crash: keep its text only
        error = outcomes.describe_error(exc)
    if error is not None:
        gc.collect()            # drop the broken scene (Dr.Jit traces every live plugin instance)
        text, res.reason = error
        res.cpu_seconds = time.process_time() - cpu0
        if isinstance(setting.expected, outcomes.Refused) and setting.expected.matches(text):
            res.outcome = outcomes.REFUSED
        else:
            res.outcome = outcomes.FAIL
            res.failures.append(("raised %s, not the expected refusal /%s/" % (res.reason, setting.expected.pattern))
                                if isinstance(setting.expected, outcomes.Refused) else "raised " + res.reason)
        return res
    res.ref_depth = spec.reference_depth(d)
    ref, res.ref_seconds = reference(scene, res.ref_depth, resolution, seed=seed, quick=quick)
    res.ref_runs, res.ref_spp = ref.shape[0], expectations.reference_budget(scene, quick)["spp"]
    res.cpu_seconds = time.process_time() - cpu0
    out = comparison.compare(images, ref, z_bound, res.bias, res.block_bias)
    for key in ("mean", "ref_mean", "se", "ref_se", "z", "limit", "tolerance", "power", "block_failures",
                "block_tests", "rmse", "false_failure", "failures"):
        setattr(res, key, out[key])
    black = math.isinf(res.power)        # a black reference: the absolute tolerance instead
    if not quick and black and not res.tolerance <= BLACK_LIMIT:
        res.failures.append("a black reference, and the comparison accepts a mean up to %.3g (limit %g)"
                            % (res.tolerance, BLACK_LIMIT))
    if not quick and not black and not res.power <= res.power_limit:
        res.failures.append("the comparison detects only a relative error of %.3g %% (limit %.3g %%)"
                            % (100 * res.power, 100 * res.power_limit))
    res.outcome = outcomes.PASS if out["passed"] and not res.failures else outcomes.FAIL
    if isinstance(setting.expected, outcomes.Refused):
        res.failures.append("rendered, but a refusal matching /%s/ was expected" % setting.expected.pattern)
    return res


#: renders with one seed agree up to the order of float additions in atomic sums (film
#: splats, patch sums), which depends on the thread schedule (README: measured relative
#: differences up to 3.5e-4 for ray_bundle, whose iterations amplify the last bits); a larger
#: difference means a seed does not fix the image
SAME_SEED_TOLERANCE = 1e-3


def same_seed(scene, integrator, seed=0, resolution=16, quick=False, repeats=3):
    """Render ``scene`` ``repeats`` times with one seed: (bit-identical, largest absolute
    difference to the first render, that difference relative to its largest |pixel|).
    The renders count as the same image when the relative difference is at most
    ``SAME_SEED_TOLERANCE``."""
    spec = expectations.spec_of(integrator)
    setting = expectations.setting(spec, scene, quick)
    images, _, _ = render_runs(SCENES[scene][0](resolution), setting.params, setting.spp,
                               _seeds(seed, 1, 2) * int(repeats))
    diff = float(np.max(np.abs(images - images[0:1])))
    scale = float(np.max(np.abs(images[0])))
    return bool(np.all(images == images[0:1])), diff, (diff / scale if scale > 0 else diff)
