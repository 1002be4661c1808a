"""Run the coverage matrix: every row of :mod:`.rows` against every package integrator.

A cell loads its row's scene with the integrator (wrapped by the row's integrator
plugin, for ``aov`` and ``moment``), renders ``runs`` images with disjoint seeds, and
compares them with the row's reference integrator (``path``, ``volpath`` for media,
``ptracer`` where ``path`` cannot see the light) by the conformance statistics
(:func:`mi_plugins.verify.conformance.compare.compare`). The outcome is

- **PASS**: the comparison passes;
- **REFUSED**: the integrator raised :class:`mi_plugins.base.errors.Unsupported` (or a
  parameter / shape error of the package) whose message names the integrator and the
  feature, before rendering anything;
- **N/A**: the row cannot be built here (its reason), or the integrator does not
  apply by design (its documented reason);
- **FAIL**: anything else: a wrong image, an unclear error, a crash, a refusal where a
  render was expected (or the reverse), a cell over :data:`SLOWNESS_LIMIT` times the
  reference's seconds per run, or a comparison blind to a relative error of the image
  mean of :data:`POWER_LIMIT` (a cell that cannot see it renders longer or is a known
  defect, never a PASS).

The expected outcome of every cell is in :mod:`.expected`; a cell whose outcome is not
the expected one fails the suite.
"""
import gc
import math
from dataclasses import dataclass, field

import numpy as np

from mi_plugins.verify.conformance import compare as comparison
from mi_plugins.verify.conformance import outcomes, renders
from mi_plugins.verify.conformance.runner import _seeds
from mi_plugins.verify.coverage import expected as expectations
from mi_plugins.verify.coverage.rows import all_rows

#: a cell slower than this many times the reference's seconds per run is a failure
SLOWNESS_LIMIT = 20.0
#: ... where the reference's seconds per run count as at least this much: below it a
#: render's time is Dr.Jit's fixed cost of tracing and launching kernels, not its work
REFERENCE_FLOOR = 0.05
#: a PASS must detect a relative error of the image mean of this size (its power: the
#: comparison's tolerance over the reference's mean); a black reference (no relative error
#: exists) an absolute error of BLACK_TOLERANCE. A Spec's ``power`` may set a stricter
#: limit for a cell, never a looser one. Quick runs (half the runs) are a first look:
#: the rule is not applied to them
POWER_LIMIT = 0.1
BLACK_TOLERANCE = 1e-4
#: film size of the cells (pixels per side)
RESOLUTION = 8
#: runs of the integrator and of the reference (quick: half)
RUNS = 8
REFERENCE_RUNS = 8
REFERENCE_SPP = 512

_ROWS = None
_REFERENCES = {}


def rows():
    global _ROWS
    if _ROWS is None:
        _ROWS = all_rows()
    return _ROWS


@dataclass
class Cell:
    row: str
    integrator: str
    expected: str = outcomes.PASS
    outcome: str = outcomes.FAIL
    reason: str = ""
    mean: float = float("nan")
    ref_mean: float = float("nan")
    z: float = float("nan")
    power: float = float("nan")
    tolerance: float = float("nan")
    false_failure: float = 0.0    # bound on a correct integrator failing the comparison
    seconds: float = 0.0          # per run of the integrator
    ref_seconds: float = 0.0      # per run of the reference
    runs: int = 0
    spp: int = 0
    warnings: list = field(default_factory=list)
    failures: list = field(default_factory=list)

    @property
    def ok(self):
        return self.outcome == self.expected

    @property
    def slowness(self):
        """Seconds per run relative to the reference's (at least ``REFERENCE_FLOOR``)."""
        return self.seconds / max(self.ref_seconds, REFERENCE_FLOOR) if self.seconds > 0 else float("nan")

    def as_dict(self):
        d = dict(self.__dict__, ok=self.ok, slowness=self.slowness)
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}

    def __repr__(self):
        head = "%s %s x %s" % (self.outcome, self.row, self.integrator)
        if not self.ok:
            head += " (expected %s)" % self.expected
        if math.isnan(self.mean):
            return head + ": " + (self.reason or "; ".join(self.failures))
        return ("%s: mean %.5g, reference %.5g (z %+.2f, detects %.2g %%), %.2f s per run (%.1fx the reference)%s"
                % (head, self.mean, self.ref_mean, self.z, 100 * self.power, self.seconds, self.slowness,
                   "".join("\n  - " + f for f in self.failures)))


def _render(scene_dict, integrator_dict, spp, seeds):
    """(images (runs, H, W, C), seconds per run, warnings); images are float64. The seconds
    are the median over the runs: the first run also compiles the scene's kernels, and a
    run that shared the machine with another process's burst does not set the ratio."""
    images, times, caught = renders.render_seeds(scene_dict, integrator_dict, spp, seeds)
    return images, float(np.median(times)) if times else 0.0, caught


def depth_of(row):
    return -1 if row.max_depth is None else int(row.max_depth)


def reference(row_key, resolution=RESOLUTION, seed=0, quick=False):
    """The row's reference renders (cached per process): (images, seconds per run)."""
    row = rows()[row_key]
    runs = row.reference_runs or REFERENCE_RUNS
    runs = max(runs // 2, 4) if quick else runs
    spp = int(REFERENCE_SPP * row.spp_scale)
    key = (row_key, resolution, seed, runs, spp)
    if key not in _REFERENCES:
        build = row.reference_scene or row.build
        integ = dict({"type": row.reference, "max_depth": depth_of(row)}, **row.params)
        images, seconds, _ = _render(build(resolution), integ, spp, _seeds(seed, runs, 1))
        _REFERENCES[key] = (images, seconds)
    return _REFERENCES[key]


def clear_references():
    _REFERENCES.clear()


def cell_integrator(row, name, quick=False):
    """(integrator dict, spp, runs) of the cell (row, integrator ``name``)."""
    spec = expectations.spec_of(name)
    params = dict(spec.params, max_depth=depth_of(row), **row.params)
    params.update(spec.row_params.get(row.key, {}))
    if row.wrap is not None:
        params = row.wrap(params)
    spp = int(spec.spp * spec.row_spp.get(row.key, 1) * (row.spp_scale if spec.scale_spp else 1))
    runs = spec.row_runs.get(row.key, spec.runs)
    return params, max(spp, 1), max(runs // 2, 4) if quick else runs


def power_limit(spec, row_key):
    """The relative error of the image mean that the cell (``spec``'s integrator, row
    ``row_key``) must detect: its ``Spec.power`` entry, else :data:`POWER_LIMIT`."""
    return spec.power.get(row_key, (POWER_LIMIT, ""))[0]


def loose_power_limits(specs=None):
    """[(integrator, row, limit)] of every ``Spec.power`` entry above :data:`POWER_LIMIT`
    (``specs``: the package's integrators by default); none is allowed."""
    specs = list(expectations.INTEGRATORS.values()) if specs is None else specs
    return [(s.name, row, limit) for s in specs for row, (limit, _) in s.power.items() if not limit <= POWER_LIMIT]


def run(row_key, integrator, seed=0, resolution=RESOLUTION, quick=False, runs=None):
    """Run one cell; returns a :class:`Cell`."""
    row = rows()[row_key]
    expect = expectations.expected(row, integrator)
    cell = Cell(row=row_key, integrator=expectations.spec_of(integrator).name,
                expected=outcomes.expected_label(expect))
    if row.na is not None or isinstance(expect, outcomes.NotApplicable):
        cell.outcome, cell.reason = outcomes.NA, row.na or expect.reason
        if cell.expected != outcomes.NA:
            cell.failures.append("N/A, but %s was expected" % cell.expected)
        return cell
    params, spp, default_runs = cell_integrator(row, integrator, quick)
    cell.runs, cell.spp = int(runs or default_runs), spp
    try:
        images, cell.seconds, cell.warnings = _render(row.build(resolution), params, spp,
                                                      _seeds(seed, cell.runs, 0))
    except Exception as exc:        # a refusal, or a crash
        text, cell.reason = outcomes.describe_error(exc)
        gc.collect()                # drop the failed scene (Dr.Jit traces every live plugin instance)
        if isinstance(expect, outcomes.Refused) and expect.matches(text):
            cell.outcome = outcomes.REFUSED
        else:
            cell.failures.append("raised %s%s" % (cell.reason, ", not the expected refusal /%s/" % expect.pattern
                                                  if isinstance(expect, outcomes.Refused) else ""))
        return cell
    ref, cell.ref_seconds = reference(row_key, resolution, seed, quick)
    out = comparison.compare(images, ref)
    for key in ("mean", "ref_mean", "z", "power", "tolerance", "false_failure"):
        setattr(cell, key, out[key])
    cell.failures += out["failures"]
    if isinstance(expect, outcomes.Refused):
        cell.failures.append("rendered, but a refusal matching /%s/ was expected" % expect.pattern)
    spec = expectations.spec_of(integrator)
    black = math.isinf(cell.power)       # a black reference: the absolute tolerance instead
    if not quick and black and not cell.tolerance <= BLACK_TOLERANCE:
        cell.failures.append("a black reference, and the cell accepts a mean up to %.3g (limit %g)"
                             % (cell.tolerance, BLACK_TOLERANCE))
    if not quick and not black and not cell.power <= power_limit(spec, row_key):
        cell.failures.append("the cell detects only a relative error of %.3g %% (limit %.3g %%)"
                             % (100 * cell.power, 100 * power_limit(spec, row_key)))
    limit = spec.slowness.get(row_key, (SLOWNESS_LIMIT, ""))[0]
    if cell.slowness > limit:
        cell.failures.append("%.2f s per run: %.0fx the reference's %.3f s (counted as at least %g s; limit %gx)"
                             % (cell.seconds, cell.slowness, cell.ref_seconds, REFERENCE_FLOOR, limit))
    cell.outcome = outcomes.PASS if not cell.failures else outcomes.FAIL
    return cell


def run_all(integrators=None, row_keys=None, seed=0, quick=False, progress=None):
    """Every selected cell, row by row; ``progress(cell)`` after each."""
    names = list(integrators or expectations.INTEGRATORS)
    cells = []
    for key in (row_keys or list(rows())):
        for name in names:
            cell = run(key, name, seed=seed, quick=quick)
            cells.append(cell)
            if progress is not None:
                progress(cell)
    return cells
