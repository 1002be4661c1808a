"""pytest plugin: check an integrator against the scenes with analytically known radiance.

Installed with the package as the ``pytest11`` entry point ``mi_plugins`` (from a source
checkout: ``pytest -p mi_plugins.verify.pytest_plugin``). Loading it costs nothing: Mitsuba is
imported, and the variant set, only when a test uses one of its fixtures or helpers, or
when ``--mi-integrator`` is given. See ``docs/pytest_plugin.md``.

Fixtures
    ``mi_variant``: makes ``llvm_ad_rgb`` the active variant (set once; again only if
    something switched it) with the package's plugins registered; returns its name.
    ``analytic_cases``: a factory, ``analytic_cases("furnace_box")`` -> AnalyticCase at
    ``--mi-resolution`` (default 16) pixels; ``.names`` and ``.quick`` list the case names.
    ``analytic_case``: one case, parametrized indirectly by name (or (name, resolution)):
    ``@pytest.mark.parametrize("analytic_case", ["furnace_box"], indirect=True)``.

Helper
    :func:`assert_matches_analytic` runs :func:`mi_plugins.verify.analytic.check` and raises
    AssertionError with the harness's report when the check fails.

Options
    ``--mi-integrator SPEC`` turns the verification matrix into test items
    ``mi_analytic[<case>]``, one per case of ``--mi-cases``, even in a folder without
    test files. SPEC: ``module:attribute`` (a factory called once, after the variant is
    set, returning a Mitsuba integrator dict or a plugin name; or a dict or a name),
    a JSON dict, a row of the package's matrix (``path``, ``stochastic_ray``, ...: that
    row's integrator dict, budget, N/A cases and known findings), or a registered
    plugin name. ``--mi-spp``, ``--mi-runs``, ``--mi-seed``, ``--mi-resolution`` set the
    budget, ``--mi-power P`` fails a passing check that cannot detect a relative error P.
"""
import dataclasses
import importlib
import json
import sys
import traceback

import pytest

#: the variant the fixtures and helpers set
VARIANT = "llvm_ad_rgb"
#: image side of the cases built by the fixtures and the matrix items (the quick resolution)
DEFAULT_RESOLUTION = 16
#: budget of assert_matches_analytic and of --mi-integrator items (16 runs: the Student-t
#: bound at the harness's z 4.5 is then 6.7 SE; with 8 runs it would be 11.9 SE)
DEFAULT_SPP = 64
DEFAULT_RUNS = 16
#: name of the matrix items: mi_analytic[<case>]
ITEM_NAME = "mi_analytic"
#: name of the pytest11 entry point in pyproject.toml
ENTRY_POINT = "mi_plugins"

_state = {"variant": None}
_items_key = pytest.StashKey()


# ---------------------------------------------------------------------------- the package
def _drop_bare_parent():
    """Forget the bare ``mi_plugins`` imported as this module's parent (see the package
    docstring), so that the next ``import mi_plugins`` is the full one."""
    parent = sys.modules.get("mi_plugins")
    if parent is not None and getattr(parent, "_BARE", False):
        for name in [n for n in sys.modules if n == "mi_plugins" or n.startswith("mi_plugins.")]:
            if name != __name__:
                del sys.modules[name]


def ensure_variant():
    """Make ``VARIANT`` the active Mitsuba variant with the package's plugins registered.
    Sets it only when no or another variant is active; returns the variant name."""
    _drop_bare_parent()
    import mitsuba as mi
    if mi.variant() == VARIANT and _state["variant"] == VARIANT:
        return VARIANT
    if mi.variant() != VARIANT:
        mi.set_variant(VARIANT)
    fresh = "mi_plugins" not in sys.modules
    package = importlib.import_module("mi_plugins")  # the full import registers the plugins
    if not fresh:
        package.register()
    _state["variant"] = VARIANT
    return VARIANT


def _analytic():
    ensure_variant()
    return importlib.import_module("mi_plugins.verify.analytic")


class CaseFactory:
    """``factory(name, resolution=None)`` -> the AnalyticCase ``name`` of the verification
    matrix at ``resolution`` pixels (default: the factory's). ``names``: every case name;
    ``quick``: the quick subset (``mi-plugins verify --quick``)."""

    def __init__(self, resolution=DEFAULT_RESOLUTION):
        self.resolution = int(resolution)
        self._table = _analytic().cases()

    @property
    def names(self):
        return list(self._table)

    @property
    def quick(self):
        from mi_plugins.verify.analytic import matrix
        return list(matrix.quick_cases())

    def __call__(self, name, resolution=None):
        if name not in self._table:
            raise ValueError("unknown analytic case %r; choose from: %s" % (name, ", ".join(self._table)))
        return self._table[name](resolution=int(resolution or self.resolution))

    def __repr__(self):
        return "CaseFactory(resolution=%d, %d cases)" % (self.resolution, len(self._table))


# ---------------------------------------------------------------------------- the helper
def failure_message(result, seed=None):
    """The harness's report of ``result`` (a CheckResult), with the seed when given, and a
    note on Mitsuba's analytic-sphere finding where a failing mean on such a case is high by
    no more than that finding explains."""
    from mi_plugins.verify.analytic import matrix
    text = repr(result)
    excess = result.mean - result.expected_mean
    if (result.applicable and not result.passed and result.case in matrix.SPHERE_NEE_CASES and result.bias == 0
            and 0 < excess <= matrix.SPHERE_NEE_BIAS * abs(result.expected_mean) + result.tolerance):
        text += ("\n  note: %s; an integrator that samples this emitter inherits a bias bounded by %.2g %% of the "
                 "mean (pass bias=matrix.SPHERE_NEE_BIAS * case.expected_mean() to allow it)"
                 % (matrix.SPHERE_NEE_FINDING, 100 * matrix.SPHERE_NEE_BIAS))
    if seed is not None:
        text += "\n  (seed %d)" % int(seed)
    return text


def assert_matches_analytic(case, integrator, spp=DEFAULT_SPP, runs=DEFAULT_RUNS, seed=0, power=None,
                            **check_options):
    """Check ``integrator`` (plugin name or Mitsuba dict) against ``case`` (an AnalyticCase,
    or a case name: built at ``DEFAULT_RESOLUTION`` pixels) with
    :func:`mi_plugins.verify.analytic.check` (``spp`` x ``runs`` independent renders from ``seed``;
    ``check_options``: its ``bias``, ``max_depth``, ``sampler``, ``z_bound``, ...).

    Returns the CheckResult when the check passes. Raises AssertionError with the harness's
    report (exact and measured mean, SE, z and its limit, the detectable relative bias,
    which of the mean / structure / per-pixel tests failed) when it fails, or when
    ``power`` is given and the passing check cannot detect a relative error of ``power``
    (its ``relative_tolerance`` is larger: the budget is too small to mean anything).
    Skips the test (``pytest.skip``) when the case declares the integrator not applicable.
    """
    __tracebackhide__ = True
    analytic = _analytic()
    if isinstance(case, str):
        case = CaseFactory()(case)
    result = analytic.check(case, integrator, spp=spp, runs=runs, seed=seed, **check_options)
    if not result.applicable:
        pytest.skip(failure_message(result))
    if not result.passed:
        raise AssertionError(failure_message(result, seed))
    if power is not None and not result.relative_tolerance <= power:
        raise AssertionError("%s\n  - the check passed but detects only a relative error of %.3g %% > power "
                             "%.3g %%: raise spp or runs" % (failure_message(result, seed),
                                                            100 * result.relative_tolerance, 100 * power))
    return result


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture
def mi_variant():
    """The active Mitsuba variant, ``llvm_ad_rgb``, with the package's plugins registered."""
    return ensure_variant()


@pytest.fixture
def analytic_cases(mi_variant, request):
    """Factory of the analytic cases by name (:class:`CaseFactory`) at ``--mi-resolution``."""
    return CaseFactory(request.config.getoption("mi_resolution"))


@pytest.fixture
def analytic_case(analytic_cases, request):
    """The analytic case named by indirect parametrization: a name, or (name, resolution)."""
    param = getattr(request, "param", None)
    if param is None:
        pytest.fail("the analytic_case fixture needs a case name: @pytest.mark.parametrize('analytic_case', "
                    "['furnace_box', ...], indirect=True); cases: %s" % ", ".join(analytic_cases.names),
                    pytrace=False)
    name, resolution = (param, None) if isinstance(param, str) else param
    try:
        return analytic_cases(name, resolution)
    except ValueError as error:
        pytest.fail(str(error), pytrace=False)


# ---------------------------------------------------------------------------- options
def pytest_addoption(parser, pluginmanager):
    _drop_bare_parent()
    # pytest refuses to register one module under two names: loaded as the entry point,
    # skip a later -p / pytest_plugins naming the module; loaded by its module name, skip
    # the entry point of an installed package
    own = pluginmanager.get_name(sys.modules[__name__])
    for other in (ENTRY_POINT, __name__):
        if other != own and not pluginmanager.has_plugin(other):
            pluginmanager.set_blocked(other)
    group = parser.getgroup("mi_plugins", "mi_plugins: analytic verification of Mitsuba integrators")
    group.addoption("--mi-integrator", metavar="SPEC", default=None,
                    help="check this integrator against the analytic cases, one test item mi_analytic[<case>] "
                         "per case: module:factory (returns a Mitsuba integrator dict or a plugin name), "
                         "a JSON dict, a row of the package's verification matrix, or a plugin name")
    group.addoption("--mi-cases", metavar="NAMES", default="quick",
                    help="comma-separated case names, 'quick' (default: the quick cases of the matrix) or 'all'")
    group.addoption("--mi-spp", metavar="N", type=int, default=None,
                    help="samples per pixel of each run (default %d; a matrix row: its quick budget)" % DEFAULT_SPP)
    group.addoption("--mi-runs", metavar="N", type=int, default=None,
                    help="independent runs per check (default %d; a matrix row: its quick budget)" % DEFAULT_RUNS)
    group.addoption("--mi-seed", metavar="N", type=int, default=0, help="seed of the checks (default 0)")
    group.addoption("--mi-resolution", metavar="N", type=int, default=DEFAULT_RESOLUTION,
                    help="image side of the cases, pixels (default %d)" % DEFAULT_RESOLUTION)
    group.addoption("--mi-power", metavar="P", type=float, default=None,
                    help="a passing check must detect a relative error P (e.g. 0.02), else it fails")


def pytest_configure(config):
    _drop_bare_parent()
    config.addinivalue_line("markers", "mi_analytic: an analytic check made by --mi-integrator")


# ---------------------------------------------------------------------------- matrix items
class IntegratorUnderTest:
    """What ``--mi-integrator text`` names: ``spec`` (a matrix IntegratorSpec), its report
    ``label``, and whether it is a row of the package's matrix (``is_row``)."""

    def __init__(self, text, spec, label, is_row):
        self.text, self.spec, self.label, self.is_row = text, spec, label, is_row

    def spec_for(self, case_name, case):
        """The spec to check ``case`` with: a user's integrator on a case inside Mitsuba's
        analytic sphere gets that finding's bounded bias, explicitly, as the package's own
        tests allow it (a row of the matrix carries its own findings)."""
        from mi_plugins.verify.analytic import matrix
        if self.is_row or case_name not in matrix.SPHERE_NEE_CASES:
            return self.spec
        return dataclasses.replace(self.spec, bias={case_name: matrix.SPHERE_NEE_BIAS * abs(case.expected_mean())})

    def not_applicable(self, case_name, case):
        """Why the integrator cannot handle ``case`` by design (the row's or the case's reason), or None."""
        return self.spec.not_applicable.get(case_name) or case.not_applicable(
            self.spec.integrator_for(case_name, quick=True))


def _user_object(target, search_dir):
    """The object ``module:attribute`` names, called when it is callable (a factory)."""
    module_name, _, attribute = target.partition(":")
    if search_dir and search_dir not in sys.path:
        sys.path.insert(0, search_dir)
    try:
        obj = importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        if error.name != module_name:
            raise ValueError("importing %s failed:\n%s" % (module_name, traceback.format_exc().rstrip())) from None
        raise ValueError("no module %s (searched %s and sys.path)" % (module_name, search_dir or "sys.path")) from None
    except Exception:
        raise ValueError("importing %s failed:\n%s" % (module_name, traceback.format_exc().rstrip())) from None
    for part in attribute.split("."):
        if not hasattr(obj, part):
            raise ValueError("%s has no attribute %s" % (module_name, attribute))
        obj = getattr(obj, part)
    if callable(obj):
        try:
            obj = obj()
        except Exception:
            raise ValueError("%s() raised:\n%s" % (target, traceback.format_exc().rstrip())) from None
    return obj


def resolve_integrator(text, search_dir=None):
    """The :class:`IntegratorUnderTest` of ``--mi-integrator text``, after setting the variant
    (a factory may register a plugin). ValueError saying what is wrong otherwise."""
    ensure_variant()
    import mitsuba as mi
    from mi_plugins.verify.analytic import harness, matrix
    text = text.strip()
    if text in matrix.INTEGRATORS:
        return IntegratorUnderTest(text, matrix.INTEGRATORS[text], text, True)
    if text.startswith("{"):
        try:
            value = json.loads(text)
        except ValueError as error:
            raise ValueError("not a valid JSON dict: %s" % error) from None
    elif ":" in text:
        value = _user_object(text, search_dir)
    else:
        value = text
    if isinstance(value, str):
        value = {"type": value}
    if not isinstance(value, dict) or not isinstance(value.get("type"), str):
        raise ValueError("must give a Mitsuba integrator dict with a 'type', or a plugin name; got %r" % (value,))
    try:
        mi.load_dict(dict(value))
    except Exception as error:
        raise ValueError("Mitsuba cannot load the integrator %r: %s" % (value, error)) from None
    spec = matrix.IntegratorSpec(dict(value), spp=DEFAULT_SPP, runs=DEFAULT_RUNS, quick_spp=DEFAULT_SPP,
                                 quick_runs=DEFAULT_RUNS)
    return IntegratorUnderTest(text, spec, harness.integrator_label(value), False)


class AnalyticFailure(AssertionError):
    """A failed analytic check; reported with the harness's message only."""


class KnownFinding(AnalyticFailure):
    """A failed check that a row of the package's matrix documents as a finding (XFAIL)."""


class AnalyticItem(pytest.Item):
    """``mi_analytic[<case>]``: the integrator of ``--mi-integrator`` on one analytic case.
    ``result``: its CheckResult once run (at collection for an N/A case)."""

    def __init__(self, *, case_name, case, under_test, **kwargs):
        super().__init__(**kwargs)
        self.case_name, self.case, self.under_test = case_name, case, under_test
        self.result = None
        self.add_marker("mi_analytic")

    def _reproduce(self):
        option = self.config.getoption
        return ("reproduce: pytest --mi-integrator '%s' --mi-cases %s --mi-seed %d --mi-resolution %d%s%s"
                % (option("mi_integrator"), self.case_name, option("mi_seed"), option("mi_resolution"),
                   "" if option("mi_spp") is None else " --mi-spp %d" % option("mi_spp"),
                   "" if option("mi_runs") is None else " --mi-runs %d" % option("mi_runs")))

    def runtest(self):
        from mi_plugins.verify.analytic import matrix
        option = self.config.getoption
        result = matrix.run_cell(self.under_test.spec_for(self.case_name, self.case), self.under_test.label,
                                 self.case_name, self.case, quick=True, seed=option("mi_seed"),
                                 spp=option("mi_spp"), runs=option("mi_runs"))
        self.result = result
        self.user_properties.append(("mi_analytic", result.as_dict()))
        message = "%s\n  %s" % (failure_message(result, option("mi_seed")), self._reproduce())
        if result.status == "XFAIL":
            raise KnownFinding(message)
        if result.status == "FAIL":
            raise AnalyticFailure(message)
        power = option("mi_power")
        if power is not None and not result.relative_tolerance <= power:
            raise AnalyticFailure("%s\n  - the check passed but detects only a relative error of %.3g %% > "
                                  "--mi-power %.3g %%: raise --mi-spp or --mi-runs"
                                  % (message, 100 * result.relative_tolerance, 100 * power))

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, AnalyticFailure):
            return str(excinfo.value)
        return super().repr_failure(excinfo, style)

    def reportinfo(self):
        return self.path / self.name, 0, self.name  # shown as mi_analytic[<case>] in reports


@pytest.hookimpl(tryfirst=True)  # before -k / -m deselect
def pytest_collection_modifyitems(session, config, items):
    text = config.getoption("mi_integrator")
    if not text:
        return
    try:
        under_test = resolve_integrator(text, str(config.invocation_params.dir))
    except ValueError as error:
        raise pytest.UsageError("--mi-integrator %s: %s" % (text, error)) from None
    from mi_plugins.verify.analytic import harness, matrix
    chosen = config.getoption("mi_cases").strip()
    if chosen in ("quick", "all"):
        names = list(matrix.quick_cases() if chosen == "quick" else matrix.all_cases())
    else:
        try:
            names = matrix.select([n.strip() for n in chosen.split(",") if n.strip()], matrix.all_cases(), "case")
        except ValueError as error:
            raise pytest.UsageError("--mi-cases: %s" % error) from None
    new = []
    for name in names:
        case = matrix.all_cases()[name](resolution=config.getoption("mi_resolution"))
        item_name = "%s[%s]" % (ITEM_NAME, name)
        item = AnalyticItem.from_parent(session, name=item_name, nodeid=item_name, case_name=name, case=case,
                                        under_test=under_test)
        reason = under_test.not_applicable(name, case)
        if reason:
            item.result = harness.CheckResult(case=name, integrator=under_test.label, spp=0, runs=0,
                                              applicable=False, reason=reason)
            item.add_marker(pytest.mark.skip(reason="N/A: " + reason))
        elif name in under_test.spec.known_failures:
            item.add_marker(pytest.mark.xfail(reason="known finding: " + under_test.spec.known_failures[name],
                                              raises=KnownFinding, strict=False))
        new.append(item)
    items.extend(new)
    config.hook.pytest_collectreport(report=pytest.CollectReport(ITEM_NAME, "passed", None, new))


def pytest_collection_finish(session):
    session.config.stash[_items_key] = [item for item in session.items if isinstance(item, AnalyticItem)]


def pytest_terminal_summary(terminalreporter, config):
    items = config.stash.get(_items_key, [])
    results = [item.result for item in items if item.result is not None]
    if not results:
        return
    from mi_plugins.verify.analytic import matrix
    terminalreporter.section("mi_analytic: %s" % items[0].under_test.label)
    for line in matrix.format_table(results).splitlines():
        terminalreporter.write_line(line)
    checked = [r for r in results if r.applicable]
    if checked:
        worst = max(checked, key=lambda r: r.relative_tolerance)
        terminalreporter.write_line("largest detectable relative bias: %.3g %% (%s); --mi-power makes a limit "
                                    "a requirement" % (100 * worst.relative_tolerance, worst.case))
