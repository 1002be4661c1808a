"""The gradient matrix behind `mi-plugins verify --gradients`: Mitsuba's differentiable
integrators x the closed-form derivatives of the analytic cases x forward / reverse mode.

Each check is :func:`mi_plugins.verify.analytic.gradients.check_gradient`. A combination an
integrator cannot handle by design is N/A with its reason; so is one whose exact value or
scene parameter is missing (a truncated depth without a closed form, a plugin that does
not expose the parameter to ``mi.traverse``): the reason is the check's own error. A
documented disagreement is run and reported as XFAIL (XPASS when it passes at this
budget); an error raised by the integrator counts as a failure.
"""
import fnmatch
from dataclasses import dataclass, field

from mi_plugins.verify.analytic import gradients, matrix

MODES = gradients.MODES


@dataclass
class GradientSpec:
    """How the gradient matrix runs one integrator: ``integrator`` (Mitsuba dict), ``modes``,
    budget per check (``spp``, ``runs``; ``quick_spp`` for --quick), ``not_applicable`` and
    ``known_failures``: {(case, parameter, mode) pattern (fnmatch, e.g. ('mirror_sphere*',
    'reflectance', '*')): reason / finding}."""
    integrator: dict
    modes: tuple = MODES
    spp: int = 64
    runs: int = 16
    quick_spp: int = 32
    not_applicable: dict = field(default_factory=dict)
    known_failures: dict = field(default_factory=dict)


def match(table, case, parameter, mode):
    """The value of the first pattern of ``table`` matching (case, parameter, mode), else ''."""
    for pattern, value in table.items():
        if all(fnmatch.fnmatchcase(v, p) for v, p in zip((case, parameter, mode), pattern)):
            return value
    return ""


#: Mitsuba 3.9.1: PRB-style integrators differentiate a BSDF through bsdf.eval(), which is
#: zero for a Dirac lobe (prb and prb_basic then raise: "not attached to the AD graph" /
#: "does not depend on the input variable(s)")
DELTA_BSDF = ("the ideal mirror's reflectance enters only through its Dirac lobe, which PRB-style integrators "
              "cannot differentiate (bsdf.eval() is zero there; Mitsuba raises)")
#: Mitsuba 3.9.1 finding: prbvolpath (and direct_projective in reverse mode) return a zero
#: derivative there instead of raising
ZERO_DELTA = ("returns a derivative of exactly 0 w.r.t. the reflectance of a delta BSDF (the ideal mirror) instead "
              "of refusing it like prb: it differentiates BSDFs through bsdf.eval(), zero for a Dirac lobe")
#: Mitsuba 3.9.1 finding: prb forward mode in scenes whose BSDFs are all delta
PRB_FORWARD_DELTA = ("prb forward mode raises a Dr.Jit error (forward-propagating across an AD edge outside its "
                     "dr.isolate_grad() scope) when every BSDF of the scene is delta (conductor, dielectric), "
                     "already at max_depth 1; reverse mode, prb_basic and path (naive AD) work")
#: Mitsuba 3.9.1 finding: prbvolpath's truncation at a finite max_depth
PRBVOLPATH_DEPTH = ("prbvolpath with a finite max_depth D also counts the BSDF-sampled emission found at depth D (its "
                    "depth test stops the loop but not the surface-emission step of that iteration): furnace box "
                    "primal 0.8346 instead of 0.75 at D = 2, 0.9895 instead of 0.9844 at D = 6 (volpath, path: exact)")
#: the analytic-sphere NEE finding of the value matrix affects derivatives the same way
SPHERE_NEE = {(case, "*", "*"): matrix.SPHERE_NEE_FINDING
              for case in ("furnace_sphere", "constant_brdf_diffuse_sphere")}

INTEGRATORS = {
    "prb": GradientSpec({"type": "prb", "max_depth": -1},
                        not_applicable={("mirror_sphere*", "reflectance", "*"): DELTA_BSDF},
                        known_failures={**SPHERE_NEE, ("mirror_sphere*", "*", "forward"): PRB_FORWARD_DELTA}),
    # no NEE, no Russian roulette: a finite depth bounds the paths of surfaces of albedo one
    "prb_basic": GradientSpec({"type": "prb_basic", "max_depth": 8},
                              not_applicable={("mirror_sphere*", "reflectance", "*"): DELTA_BSDF}),
    "prbvolpath": GradientSpec({"type": "prbvolpath", "max_depth": -1}, modes=("reverse",),
                               known_failures={**SPHERE_NEE,
                                               ("mirror_sphere*", "reflectance", "*"): "prbvolpath " + ZERO_DELTA}),
    "prbvolpath+depth6": GradientSpec({"type": "prbvolpath", "max_depth": 6}, modes=("reverse",),
                                      known_failures={("*", "*", "*"): PRBVOLPATH_DEPTH}),
    # direct light only (its own max_depth 2); one specular bounce to an emitter is included
    "direct_projective": GradientSpec({"type": "direct_projective"},
                                      not_applicable={("mirror_sphere*", "reflectance", "forward"): DELTA_BSDF},
                                      known_failures={**SPHERE_NEE, ("mirror_sphere*", "reflectance", "reverse"):
                                                      "direct_projective in reverse mode " + ZERO_DELTA}),
    # Mitsuba's C++ path tracer under Dr.Jit's naive AD (the whole path graph is recorded)
    "path": GradientSpec({"type": "path", "max_depth": 6}, spp=32, quick_spp=16, known_failures=dict(SPHERE_NEE)),
}


def all_cases():
    """{case name: factory} of the matrix cases with closed-form derivatives."""
    return {name: factory for name, factory in matrix.all_cases().items() if factory(resolution=1).derivatives}


def quick_cases():
    return ("furnace_box", "diffuse_sphere", "mirror_sphere", "sierpinski_phong_simulated")


def run(integrators=None, scenes=None, quick=False, seed=0, resolution=None, progress=None):
    """Run the gradient matrix; returns a list of GradientResult (``progress(result)`` after each)."""
    table = all_cases()
    case_names = matrix.select(scenes, quick_cases() if quick and not scenes else table, "scene")
    integ_names = matrix.select(integrators, INTEGRATORS, "integrator")
    res = resolution or (8 if quick else 16)
    results = []
    for case_name in case_names:
        case = table[case_name](resolution=res)
        for parameter in case.derivatives:
            for integ_name in integ_names:
                spec = INTEGRATORS[integ_name]
                for mode in MODES:
                    r = _check(case, parameter, spec, mode, quick, seed)
                    r.case, r.integrator = case_name, integ_name
                    results.append(r)
                    if progress:
                        progress(r)
    return results


def _check(case, parameter, spec, mode, quick, seed):
    reason = ("%s has no %s mode" % (spec.integrator["type"], mode) if mode not in spec.modes
              else match(spec.not_applicable, case.name, parameter, mode))
    known = match(spec.known_failures, case.name, parameter, mode)
    if not reason:
        try:
            r = gradients.check_gradient(case, spec.integrator, parameter, spp=spec.quick_spp if quick else spec.spp,
                                         runs=spec.runs, seed=seed, mode=mode)
        except ValueError as e:       # no exact value at this depth, parameter not exposed, ...
            reason = str(e)
        except Exception as e:        # raised by the integrator (Mitsuba raises plain Exceptions too): a failure
            r = gradients.GradientResult(case=case.name, integrator="", spp=spec.spp, runs=spec.runs,
                                         parameter=parameter, mode=mode, failures=["error: %s" % e])
    if reason:
        r = gradients.GradientResult(case=case.name, integrator="", spp=0, runs=0, applicable=False, reason=reason,
                                     parameter=parameter, mode=mode)
    r.known_failure = known if r.applicable else ""
    return r


COLUMNS = ("case", "parameter", "integrator", "mode", "exact", "measured", "SE", "z", "seconds", "status")


def table_rows(results):
    rows = []
    for r in results:
        head = (r.case, r.parameter, r.integrator, r.mode)
        if not r.applicable:
            rows.append(head + ("", "", "", "", "", "N/A: " + r.reason))
        elif r.failures and r.failures[0].startswith("error:"):
            rows.append(head + ("", "", "", "", "", r.status + ": raised"))
        else:
            rows.append(head + ("%.5f" % r.expected_mean, "%.5f" % r.mean, "%.2g" % r.se, "%+.2f" % r.z,
                                "%.2f" % r.seconds, r.status))
    return rows


def format_table(results):
    rows = [COLUMNS] + table_rows(results)
    widths = [max(len(str(row[i])) for row in rows) for i in range(len(COLUMNS) - 1)]
    return "\n".join("  ".join(str(v).ljust(w) for v, w in zip(row[:-1], widths)) + "  " + str(row[-1])
                     for row in rows)


def write_reports(results, directory):
    """Write gradients.json and gradients.md into ``directory``; returns their paths."""
    return matrix.write_reports(results, directory, name="gradients", columns=COLUMNS, rows=table_rows,
                                label=lambda r: "%s, dL/d%s, %s, %s mode" % (r.case, r.parameter, r.integrator,
                                                                            r.mode))


__all__ = ["INTEGRATORS", "GradientSpec", "all_cases", "quick_cases", "run", "format_table", "write_reports"]
