"""``verify()``: run the scene x integrator table, print it, write JSON/Markdown reports."""
import json
import math
import os
import time

from ..analytic.matrix import select
from mi_plugins.verify.conformance import expectations, outcomes, runner
from .scene_library import SCENES

COLUMNS = ("scene", "integrator", "outcome", "mean", "path mean", "z", "power", "seconds")


def _num(v, fmt):
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt % v


def row(r):
    """The table row of a :class:`runner.Result` (strings)."""
    outcome = r.outcome if r.ok else "%s (expected %s)" % (r.outcome, r.expected)
    if math.isnan(r.power):
        power = ""
    else:    # a black reference has no relative error: the absolute tolerance instead
        power = "abs %.2g" % r.tolerance if math.isinf(r.power) else "%.2g %%" % (100 * r.power)
    return (r.scene, r.integrator, outcome, _num(r.mean, "%.5g"), _num(r.ref_mean, "%.5g"), _num(r.z, "%+.2f"),
            power, "%.1f" % (r.seconds + r.ref_seconds) if r.outcome != outcomes.NA else "")


def note(r):
    """Why a combination is not a plain PASS: the N/A reason, the refusal, the failures."""
    if r.outcome == outcomes.NA:
        return r.reason
    if r.outcome == outcomes.REFUSED:
        return "refused as expected: " + r.reason
    return "; ".join(r.failures)


def format_table(results):
    rows = [COLUMNS] + [row(r) for r in results]
    widths = [max(len(x[i]) for x in rows) for i in range(len(COLUMNS))]
    return "\n".join("  ".join(v.ljust(w) for v, w in zip(x, widths)).rstrip() for x in rows)


def markdown(results, determinism, seconds):
    lines = ["# Conformance suite: package integrators against Mitsuba's `path`", "",
             "Created %s; %.0f s. Outcomes: PASS, REFUSED (expected refusal), N/A (documented), FAIL." %
             (time.strftime("%Y-%m-%d %H:%M"), seconds), "",
             "| " + " | ".join(COLUMNS) + " | note |", "|" + "---|" * (len(COLUMNS) + 1)]
    for r in results:
        lines.append("| " + " | ".join(row(r)) + " | " + note(r).replace("|", "/") + " |")
    if determinism:
        lines += ["", "One seed, three renders (the same image up to float summation order: relative difference "
                      "<= %.0e):" % runner.SAME_SEED_TOLERANCE, ""]
        for name, (scene, identical, diff, rel) in determinism.items():
            lines.append("- %s on %s: %s" % (name, scene, "bit-identical" if identical else
                                            "largest difference %.3g (relative %.2g)%s"
                                            % (diff, rel, "" if rel <= runner.SAME_SEED_TOLERANCE else ": FAIL")))
    return "\n".join(lines) + "\n"


def write_reports(results, determinism, directory, seconds):
    """Write conformance.json and conformance.md into ``directory``; returns their paths."""
    os.makedirs(directory, exist_ok=True)
    json_path = os.path.join(directory, "conformance.json")
    md_path = os.path.join(directory, "conformance.md")
    with open(json_path, "w") as f:
        json.dump({"created": time.strftime("%Y-%m-%dT%H:%M:%S"), "seconds": seconds,
                   "results": [r.as_dict() for r in results],
                   "same_seed": {k: {"scene": s, "identical": i, "largest_difference": d, "relative": r}
                                 for k, (s, i, d, r) in determinism.items()}}, f, indent=2)
    with open(md_path, "w") as f:
        f.write(markdown(results, determinism, seconds))
    return json_path, md_path


def verify(integrators=None, scenes=None, quick=False, report=None, out=print, seed=0, same_seed=True):
    """Run every selected (scene, integrator) combination against ``path``; print a table.

    ``integrators``/``scenes``: names (default: all; ``scenes()`` and
    ``expectations.INTEGRATORS`` list them); the expected refusals of
    ``expectations.REFUSALS`` run too when their scene and plugin are selected;
    ``quick``: half the runs (less power); ``report``: a directory for conformance.json
    and conformance.md; ``out``: where lines go (``print``); ``same_seed``: also render
    each integrator three times with one seed on the first scene it passed and require
    the same image (up to the float summation order of atomic sums:
    ``runner.SAME_SEED_TOLERANCE``).
    Returns the exit status: 0 when every outcome is the expected one (PASS, or the
    expected REFUSED / N/A) and one seed fixes every integrator's image, 1 otherwise.
    """
    scene_names = select(scenes, SCENES, "scene")
    integ_names = select(integrators, expectations.INTEGRATORS, "integrator")
    t0 = time.perf_counter()
    jobs = [(scene, name) for scene in scene_names for name in integ_names]
    # the expected refusals of variants outside the main table (e.g. the paper's ray_bundle)
    jobs += [(scene, spec) for scene, spec in expectations.REFUSALS
             if scene in scene_names and spec.params["type"] in integ_names]
    results = []
    for scene, name in jobs:
        r = runner.run(scene, name, seed=seed, quick=quick)
        results.append(r)
        out("  %-8s %-26s %-15s %s" % (r.outcome if r.ok else r.outcome + "!", scene, r.integrator,
                                       note(r)[:90] if r.outcome in (outcomes.NA, outcomes.REFUSED) or not r.ok
                                       else "z %+.2f  %.1f s" % (r.z, r.seconds + r.ref_seconds)))
    determinism = {}
    if same_seed:
        for name in integ_names:
            applicable = [r.scene for r in results if r.integrator == name and r.outcome == outcomes.PASS]
            if applicable:
                determinism[name] = (applicable[0],) + runner.same_seed(applicable[0], name, seed=seed, quick=quick)
    seconds = time.perf_counter() - t0
    out("")
    out(format_table(results))
    counts = {k: sum(r.outcome == k for r in results) for k in (outcomes.PASS, outcomes.REFUSED, outcomes.NA,
                                                                outcomes.FAIL)}
    unexpected = [r for r in results if not r.ok]
    nondet = [k for k, (_, _, _, rel) in determinism.items() if rel > runner.SAME_SEED_TOLERANCE]
    out("\n%d PASS, %d REFUSED, %d N/A, %d FAIL; %d not as expected%s (%.0f s)"
        % (counts[outcomes.PASS], counts[outcomes.REFUSED], counts[outcomes.NA], counts[outcomes.FAIL],
           len(unexpected), "; a seed does not fix the image: " + ", ".join(nondet) if nondet else "", seconds))
    for r in unexpected:
        out("\n" + repr(r))
    if report:
        for path in write_reports(results, determinism, report, seconds):
            out("wrote " + path)
    return 1 if unexpected or nondet else 0
