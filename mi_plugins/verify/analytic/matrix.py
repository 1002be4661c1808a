"""The integrator x case verification matrix behind `mi-plugins verify`.

To add an integrator, add an :class:`IntegratorSpec` to ``INTEGRATORS``.
"""
import json
import os
import time
from dataclasses import dataclass, field, replace

from mi_plugins.verify.analytic import classic, constant_radiance, harness


@dataclass
class IntegratorSpec:
    """How the matrix runs one integrator.

    ``integrator``: Mitsuba dict; ``spp``/``runs``: budget per check (``quick_spp`` /
    ``quick_runs`` for --quick); ``bias``: {case name: known bounded bias}; ``not_applicable``: {case name: reason};
    ``known_failures``: {case name: documented finding}: such a check is still run and
    reported, as XFAIL when it fails and XPASS when it passes at this budget.
    ``case_params``: {case name: {parameter: value}} merged into ``integrator`` for that
    case (e.g. a longer burn-in where the albedo is close to one); ``quick_params`` and
    ``quick_case_params`` the same for --quick (merged on top).
    Budgets: 16 runs (the Student-t bound at z 4.5 is then 6.7 SE; with 8 runs it would
    be 11.9 SE for the same total cost).
    """
    integrator: dict
    spp: int = 64
    runs: int = 16
    quick_spp: int = 16
    quick_runs: int = 16
    bias: dict = field(default_factory=dict)
    not_applicable: dict = field(default_factory=dict)
    sampler: dict = None
    known_failures: dict = field(default_factory=dict)
    #: max_depth of the exact value to compare with (None: the integrator's own)
    exact_depth: int = None
    case_params: dict = field(default_factory=dict)
    quick_params: dict = field(default_factory=dict)
    quick_case_params: dict = field(default_factory=dict)

    def integrator_for(self, case_name, quick=False):
        d = dict(self.integrator, **self.case_params.get(case_name, {}))
        if quick:
            d.update(self.quick_params)
            d.update(self.quick_case_params.get(case_name, {}))
        return d


#: Mitsuba 3.9.1 finding (README, "Findings"): next-event estimation on the analytic
#: sphere from points on the sphere itself over-estimates each bounce by about 0.14 %.
SPHERE_NEE_FINDING = ("Mitsuba's analytic-sphere emitter sampling from points on the sphere itself "
                      "over-estimates direct light by ~0.14 % per bounce (README: Findings)")
#: bound of that finding's effect on the untruncated image mean, relative (measured with
#: `path` and `volpath`, 1024 spp x 16 runs: +0.17 % on furnace_sphere, +0.13 % on
#: constant_brdf_diffuse_sphere)
SPHERE_NEE_BIAS = 0.003
_SPHERE_NEE = {"furnace_sphere": SPHERE_NEE_FINDING, "constant_brdf_diffuse_sphere": SPHERE_NEE_FINDING}
#: the package's integrators with next-event estimation see the same finding on the
#: analytic-sphere cases of uniform emission (their errors are small enough to show it:
#: qmc_lighttrace 1.0011 +- 0.00007 on furnace_sphere); on the textured ones (diffuse_sphere,
#: bekaert_sphere) they sample the light themselves (mi_plugins.light.sources) and pass
_SPHERE_NEE_ALL = dict(_SPHERE_NEE)
#: the cases on Mitsuba's analytic sphere, where any integrator that samples its emitter sees the finding
SPHERE_NEE_CASES = tuple(dict(_SPHERE_NEE, diffuse_sphere=SPHERE_NEE_FINDING, bekaert_sphere=SPHERE_NEE_FINDING))
#: qmc_lighttrace on the textured analytic-sphere interiors at unbounded depth: measured
#: 0.7706 against 0.8455 (diffuse_sphere, z -598) and 0.9420 against 1 (bekaert_sphere),
#: the same before and after the package sampled textured lights itself; right at
#: max_depth 2 and 3 (0.61915 / 0.73239 against path's 0.61877 / 0.73191): cause not
#: located (it had been listed under the sphere finding above)
QMC_TEXTURED_SPHERE = ("qmc_lighttrace on the textured analytic-sphere interior at unbounded depth: about -9 % "
                       "(diffuse_sphere) / -6 % (bekaert_sphere), right at max_depth 2 and 3; cause not located")

#: qmc_lighttrace's patch bias of the indirect light in constant-radiance cases (absolute, radiance
#: ~1; measured -0.02 +- 0.01 % on the mirror box, -0.03 +- 0.03 % on Bekaert's Sierpinski case at
#: the default patch size, tests/test_qmc_lighttrace.py)
QMC_PATCH_BIAS = 5e-4

#: cases with albedos close to one, where stochastic iteration needs a longer burn-in
HIGH_ALBEDO_CASES = ("bekaert_box", "bekaert_sphere", "bekaert_sierpinski", "constant_brdf_diffuse_sphere",
                     "constant_brdf_phong_box", "constant_brdf_roughconductor_box",
                     "constant_brdf_roughplastic_sierpinski", "sierpinski_phong_simulated",
                     "constant_lightsource_sierpinski", "constant_lightsource_box")

#: ray_bundle reflects between two independent random global directions, so it cannot
#: importance-sample a narrow lobe: measured on the alpha = 0.3 roughconductor box
#: 0.47 +- 0.17 (exact 1, 128 iterations x 8 runs, RMSE 1.3): unbiased, but the mean is
#: carried by rare spikes, so a t-test on a few runs is meaningless there.
_MIRRORS = {name: "the light reaches the camera only through ideal mirrors: transport through delta surfaces "
                   "is not captured by finite elements (patches of the mirror store nothing)"
             for name in ("mirror_sphere", "mirror_sphere_cos4")}

RAY_BUNDLE_GLOSSY = ("narrow glossy lobe (roughconductor alpha 0.3): random pairs of global directions almost "
                     "never sample the lobe, the estimate is dominated by rare spikes (measured 0.47 +- 0.17, "
                     "RMSE 1.3); use stochastic_ray or path")

#: this package's samplers, each with `path` in the matrix
PACKAGE_SAMPLERS = ("sobol", "halton", "faure", "padded_sobol", "zsobol", "lattice", "cmj")
#: Mitsuba 3.9.1's samplers; the first is the default (the rows without "+sampler")
MITSUBA_SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
#: Mitsuba 3.9.1 finding (README, "Findings"): samplers whose dimensions are coupled
SAMPLER_DEPENDENCE_FINDING = (
    "Mitsuba's %s sampler couples the dimensions of one sample (its per-dimension permutation seeds are "
    "consecutive integers, which its permutation does not decorrelate): paths are drawn from a wrong joint "
    "density (README: Findings)")
#: the samplers whose matrix rows fail at the matrix budgets (measured with `path`,
#: `volpath`, `ptracer` and `prb` on every case: ldsampler on 36 of 100 checks, |z| up to 64;
#: stratified, whose 32 spp round to 36, on 4, |z| up to 14): every case is a known failure,
#: reported as XFAIL, or as XPASS where that check passes at the budget
DEPENDENT_SAMPLERS = ("stratified", "ldsampler")


def _ray_bundle(params, averaged, quick_averaged, **spec):
    """A ray_bundle row: ``averaged`` iterations after the burn-in (8; 32 on the
    high-albedo cases); --quick uses 16 chains of 16^2 lines and ``quick_averaged``."""
    def iterations(burn_in, n):
        return {"burn_in": burn_in, "iterations": burn_in + n}
    quick = dict({"chains": 16, "resolution": 16}, **spec.pop("quick_params", {}))
    paper = {"type": "ray_bundle", "chains": 1, "first_shot": False, "average_diffuse": False}  # unless `params` says
    return IntegratorSpec(dict(paper, **params, **iterations(8, averaged)), spp=1, quick_spp=1,
                          case_params={name: iterations(32, averaged) for name in HIGH_ALBEDO_CASES},
                          quick_params=dict(quick, **iterations(8, quick_averaged)),
                          quick_case_params={name: iterations(32, quick_averaged) for name in HIGH_ALBEDO_CASES},
                          not_applicable=dict(_MIRRORS, constant_brdf_roughconductor_box=RAY_BUNDLE_GLOSSY), **spec)


INTEGRATORS = {
    "path": IntegratorSpec({"type": "path"}, spp=32, quick_spp=8, known_failures=dict(_SPHERE_NEE)),
    "ptracer": IntegratorSpec({"type": "ptracer"}, spp=128, quick_spp=32),
    "volpath": IntegratorSpec({"type": "volpath"}, spp=32, quick_spp=8, known_failures=dict(_SPHERE_NEE)),
    # Mitsuba's integrators with other samplers: see _sampler_rows below
    "ptracer+sobol": IntegratorSpec({"type": "ptracer"}, spp=128, quick_spp=32, sampler={"type": "sobol"}),
    "prb": IntegratorSpec({"type": "prb", "max_depth": -1}, spp=32, quick_spp=8, known_failures=dict(_SPHERE_NEE)),
    # Keller's method, unbounded (Mitsuba's max_depth -1): its gathered diffuse points take
    # their direct light from light samples and the patches average the light of particle
    # hits k >= 2, which is not constant where the radiance is (its complement, the direct
    # light, varies over a patch): bounded by QMC_PATCH_BIAS at the default patch size.
    "qmc_lighttrace": IntegratorSpec({"type": "qmc_lighttrace", "samples": 20000, "gather_samples": 16},
                                     spp=32, quick_spp=64, quick_params={"gather_samples": 4},
                                     exact_depth=-1, known_failures=dict(_SPHERE_NEE_ALL,
                                                                         diffuse_sphere=QMC_TEXTURED_SPHERE,
                                                                         bekaert_sphere=QMC_TEXTURED_SPHERE),
                                     bias={name: QMC_PATCH_BIAS for name in (
                                         "furnace_box", "furnace_sphere", "furnace_sphere_mesh", "furnace_sierpinski",
                                         "keller_cube", "bekaert_box", "bekaert_sierpinski", "diffuse_sphere",
                                         "diffuse_sphere_mesh", "bekaert_sphere", "constant_brdf_diffuse_sphere",
                                         "sierpinski_diffuse_exact", "sierpinski_diffuse_simulated")}),
    # Stochastic iteration (Szirmay-Kalos). The image averages the iterations after
    # `burn_in`; what is missing is the power defect of the paper's eq. 20, about
    # lambda^burn_in / (1 - lambda)^2 for the scene's largest albedo lambda. It is far below
    # the error bars with the default burn-in for albedos up to ~0.5; the cases closer to
    # one (constant-radiance BRDF / lightsource scenes, Bekaert's 0.8 albedo) get a longer one.
    "stochastic_ray": IntegratorSpec({"type": "stochastic_ray", "iterations": 32, "burn_in": 8},
                                     spp=4, quick_spp=4,
                                     case_params={name: {"iterations": 96, "burn_in": 64}
                                                  for name in HIGH_ALBEDO_CASES}),
    # the paper's global ray bundles: one chain of 64^2 lines
    "ray_bundle": _ray_bundle({"resolution": 64}, 64, 8, quick_params={"chains": 32}),
    # the same with direct light by next-event estimation (first_shot), in the chain
    # configuration the benchmark uses (64 chains x 32^2 lines)
    "ray_bundle+first_shot": _ray_bundle({"resolution": 32, "chains": 64, "first_shot": True}, 24, 8,
                                         known_failures=dict(_SPHERE_NEE_ALL)),
    # and with the final gathering from averaged diffuse patches (average_diffuse). The
    # direct light is averaged too (gather_nee=false): the cases' reflected radiance is
    # constant per patch, but not its direct part where neighbouring faces emit differently
    # (Bekaert box: -0.6 % with gather_nee=true, a discretisation effect, see the tests)
    "ray_bundle+average": _ray_bundle({"resolution": 32, "chains": 64, "first_shot": True, "average_diffuse": True,
                                       "gather_nee": False}, 24, 8, known_failures=dict(_SPHERE_NEE_ALL)),
}


def _sampler_rows():
    """`path` with each of this package's samplers (``path+sobol``, ...), and each of
    Mitsuba's four integrators with each of Mitsuba's samplers (``path+stratified``, ...):
    the integrator's budget, the sampler rounding its sample count as it does."""
    rows = {"path+" + sampler: replace(INTEGRATORS["path"], sampler={"type": sampler}) for sampler in PACKAGE_SAMPLERS}
    for integrator in ("path", "volpath", "ptracer", "prb"):
        base = INTEGRATORS[integrator]
        for sampler in MITSUBA_SAMPLERS[1:]:
            findings = dict(base.known_failures)
            if sampler in DEPENDENT_SAMPLERS:
                findings.update({case: SAMPLER_DEPENDENCE_FINDING % sampler for case in all_cases()})
            rows["%s+%s" % (integrator, sampler)] = replace(base, sampler={"type": sampler}, known_failures=findings)
    return rows


def all_cases():
    return {**classic.MATRIX_CASES, **constant_radiance.MATRIX_CASES}


INTEGRATORS.update(_sampler_rows())


def quick_cases():
    return tuple(classic.QUICK_CASES) + tuple(constant_radiance.QUICK_CASES)


def select(names, available, what):
    """``names`` checked against ``available`` (all of them when ``names`` is empty)."""
    if not names:
        return list(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        raise ValueError("unknown %s %s; choose from: %s" % (what, ", ".join(unknown), ", ".join(available)))
    return list(names)


def run(integrators=None, scenes=None, quick=False, seed=0, resolution=None, progress=None):
    """Run the matrix; returns a list of CheckResult. ``progress(result)`` is called after each."""
    table = all_cases()
    case_names = select(scenes, quick_cases() if quick and not scenes else table, "scene")
    integ_names = select(integrators, INTEGRATORS, "integrator")
    res = resolution or (16 if quick else 32)
    results = []
    for case_name in case_names:
        case = table[case_name](resolution=res)
        for integ_name in integ_names:
            r = run_cell(INTEGRATORS[integ_name], integ_name, case_name, case, quick=quick, seed=seed)
            results.append(r)
            if progress:
                progress(r)
    return results


def run_cell(spec, label, case_name, case, quick=False, seed=0, spp=None, runs=None):
    """One check of the matrix: the :class:`IntegratorSpec` ``spec`` (reported as ``label``)
    on ``case`` (an AnalyticCase, reported as ``case_name``) at the spec's budget, or at
    ``spp`` / ``runs`` where given. Returns the CheckResult (N/A without rendering)."""
    if case_name in spec.not_applicable:
        r = harness.CheckResult(case=case_name, integrator=label, spp=0, runs=0, applicable=False,
                                reason=spec.not_applicable[case_name])
    else:
        r = harness.check(case, spec.integrator_for(case_name, quick),
                          spp=spp or (spec.quick_spp if quick else spec.spp),
                          runs=runs or (spec.quick_runs if quick else spec.runs), seed=seed,
                          bias=max(spec.bias.get(case_name, 0.0), case.known_bias), sampler=spec.sampler,
                          max_depth=spec.exact_depth)
        r.integrator = label
        # a documented finding excuses a biased value, never a NaN or infinite pixel
        if case_name in spec.known_failures and not any("non-finite" in f for f in r.failures):
            r.known_failure = spec.known_failures[case_name]
    r.case = case_name
    return r


COLUMNS = ("case", "integrator", "exact", "measured", "SE", "z", "RMSE", "seconds", "status")


def table_rows(results):
    rows = []
    for r in results:
        if not r.applicable:
            rows.append((r.case, r.integrator, "", "", "", "", "", "", "N/A: " + r.reason))
            continue
        rows.append((r.case, r.integrator, "%.5f" % r.expected_mean, "%.5f" % r.mean, "%.2g" % r.se,
                     "%+.2f" % r.z, "%.4f" % r.rmse, "%.2f" % r.seconds, r.status))
    return rows


def format_table(results):
    rows = [COLUMNS] + table_rows(results)
    widths = [max(len(str(row[i])) for row in rows if i < len(row) and not str(row[i]).startswith("N/A"))
              for i in range(len(COLUMNS))]
    lines = []
    for row in rows:
        lines.append("  ".join(str(v).ljust(w) for v, w in zip(row[:-1], widths[:-1])) + "  " + str(row[-1]))
    return "\n".join(lines)


def write_reports(results, directory, name="verify", columns=COLUMNS, rows=table_rows,
                  label=lambda r: "%s x %s" % (r.case, r.integrator)):
    """Write ``name``.json and ``name``.md into ``directory``; returns their paths. The
    gradient matrix passes its own name, columns, rows and failure label."""
    os.makedirs(directory, exist_ok=True)
    json_path = os.path.join(directory, name + ".json")
    md_path = os.path.join(directory, name + ".md")
    with open(json_path, "w") as f:
        json.dump({"created": time.strftime("%Y-%m-%dT%H:%M:%S"), "results": [r.as_dict() for r in results]},
                  f, indent=2)
    with open(md_path, "w") as f:
        title = "mi-plugins verify" + ("" if name == "verify" else " --" + name)
        f.write("# %s\n\n| " % title + " | ".join(columns) + " |\n|" + "---|" * len(columns) + "\n")
        for row in rows(results):
            f.write("| " + " | ".join(str(v) for v in row) + " |\n")
        failed = [r for r in results if r.applicable and not r.passed]
        for r in failed:
            f.write("\n**%s %s**: %s%s\n" % (r.status, label(r), "; ".join(r.failures),
                                              (" (known: %s)" % r.known_failure) if r.known_failure else ""))
    return json_path, md_path
