"""The coverage matrix: every feature Mitsuba can put in a scene against every package
integrator (``mi_plugins.coverage``; the table is ``docs/coverage.md``).

One test per cell: its outcome must be the expected one (PASS, or the documented
REFUSED / N/A of ``mi_plugins.coverage.expected``), a PASS must see a relative error of
the image mean of ``POWER_LIMIT`` and run within ``matrix.SLOWNESS_LIMIT`` times the
reference's seconds per run. The catalogue test fails when the installed Mitsuba ships
a plugin without a row. Tests of the matrix itself: a deliberately wrong integrator
fails, a refusal with the wrong message fails, a slow cell fails.
"""
import math

import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.conformance import outcomes
from mi_plugins.coverage import catalog, expected, matrix, rows

#: every PASS of this file must detect a relative error of the image mean of this size,
#: except the cells an integrator's ``Spec.power`` names with their reason (at most
#: MAX_POWER_LIMIT: a cell blind to a factor of two would not be a test)
POWER_LIMIT = 0.1
MAX_POWER_LIMIT = 0.5
#: the largest slowness a cell's ``Spec.slowness`` exception may allow, with its reason
MAX_SLOWNESS_LIMIT = 50.0
SEED = 2000

ROWS = list(matrix.rows())
INTEGRATORS = list(expected.INTEGRATORS)
#: rows whose rendered cells run in every test run: the defects the matrix was built to
#: catch (non-diffuse materials, null and dielectric surfaces, bump maps, environment
#: maps, a lamp facing a ceiling, negative emission, alpha, depth); every other row
#: renders one cell in every test run (:func:`row_cells`), its other rendered cells are
#: in the extended tier (``make test-extended``); the refused and N/A cells (no render)
#: always run
ALWAYS = ("bsdf:roughconductor", "bsdf:conductor", "bsdf:plastic", "bsdf:dielectric", "bsdf:null", "bsdf:mask",
          "bsdf:bumpmap", "emitter:spot", "emitter:envmap", "format:rgba", "case:light_facing_ceiling",
          "case:negative_emission", "depth:2", "package:phong", "package:simulated_area", "case:textured_area_sphere",
          "sensor:radiancemeter")


def row_cells():
    """The rendered cell of every other row that runs in every test run: one integrator per
    row, taken in turn from the row's rendered integrators (row k, its k-th modulo their
    number), so that every row renders in every test run and each integrator gets about
    the same share of the rows; the rest of the row is in the extended tier."""
    chosen, k = {}, 0
    for r in ROWS:
        rendered = [i for i in INTEGRATORS if expected.expected(matrix.rows()[r], i) == outcomes.PASS]
        if rendered and r not in ALWAYS:
            chosen[r] = rendered[k % len(rendered)]
            k += 1
    return chosen


def _cells():
    every_run = row_cells()
    for r in ROWS:
        for i in INTEGRATORS:
            rendered = expected.expected(matrix.rows()[r], i) == outcomes.PASS
            marks = [pytest.mark.extended] if rendered and r not in ALWAYS and every_run.get(r) != i else []
            yield pytest.param(r, i, marks=marks, id="%s-%s" % (r, i))


def test_every_mitsuba_plugin_has_a_row():
    plugins = catalog.mitsuba_plugins()
    covered = {row.plugin for row in matrix.rows().values() if row.plugin}
    missing = sorted(set(plugins) - covered)
    assert not missing, "Mitsuba plugins without a coverage row: %s" % ", ".join(missing)
    assert "other" not in plugins.values(), plugins


def test_rows_name_installed_plugins():
    plugins = catalog.mitsuba_plugins()
    from mi_plugins import registry
    own = {name for kinds in registry.plugin_table().values() for name in kinds}
    for key, row in matrix.rows().items():
        if row.plugin is not None:
            assert row.plugin in plugins or row.plugin in own, key
            if row.plugin in plugins and row.kind not in ("package", "case", "format", "depth"):
                assert plugins[row.plugin] == row.kind, (key, plugins[row.plugin])


def test_always_run_rows_exist():
    assert set(ALWAYS) <= set(ROWS), sorted(set(ALWAYS) - set(ROWS))


def test_every_row_runs_in_every_test_run():
    """Every row has a cell outside the extended tier, and every integrator renders some
    of the rows that are not regression rows."""
    default = {}
    for cell in _cells():
        if not cell.marks:
            default.setdefault(cell.values[0], set()).add(cell.values[1])
    assert set(default) == set(ROWS), sorted(set(ROWS) - set(default))
    assert set(row_cells().values()) == set(INTEGRATORS), row_cells()


def test_expectations_name_rows():
    for spec in expected.INTEGRATORS.values():
        for table in (spec.refused, spec.na, spec.row_params, spec.row_spp, spec.row_runs, spec.power, spec.slowness):
            for key in table:
                assert key in matrix.rows(), (spec.name, key)
        for key, (limit, why) in spec.power.items():
            assert POWER_LIMIT < limit <= MAX_POWER_LIMIT and why, (spec.name, key)
        for key, (limit, why) in spec.slowness.items():
            assert matrix.SLOWNESS_LIMIT < limit <= MAX_SLOWNESS_LIMIT and why, (spec.name, key)


@pytest.mark.parametrize("row,integrator", list(_cells()))
def test_cell(row, integrator):
    cell = matrix.run(row, integrator, seed=budget.seed(SEED))
    assert cell.ok, repr(cell)
    if cell.outcome == outcomes.PASS:
        budget.record("coverage", cell.false_failure, row=row, integrator=integrator,
                      power=None if math.isinf(cell.power) else float(cell.power))
        if math.isinf(cell.power):       # a black reference: the absolute tolerance
            assert cell.tolerance <= 1e-4, repr(cell)
        else:
            limit = expected.spec_of(integrator).power.get(row, (POWER_LIMIT, ""))[0]
            assert cell.power <= limit, "the cell detects only %.3g %% (limit %.3g %%): %r" % (
                100 * cell.power, 100 * limit, cell)


# ------------------------------------------------------------------ the matrix's own tests
class _ScaledPath(mi.SamplingIntegrator):
    """``path`` with its image scaled: a deliberately wrong integrator."""

    def __init__(self, props):
        super().__init__(props)
        self.scale = props.get("scale", 1.0)
        self.inner = mi.load_dict({"type": "path", "max_depth": props.get("max_depth", -1)})

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        return mi.TensorXf(np.array(self.inner.render(scene, sensor, seed, spp, develop, evaluate)) * self.scale)


class _Refusing(mi.SamplingIntegrator):
    def __init__(self, props):
        super().__init__(props)
        props.get("max_depth", -1)     # every cell passes its depth

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        from mi_plugins.support import Unsupported
        raise Unsupported("coverage_refusing", "diffuse", "the BSDF 'diffuse' of shape 'subject'", "a test",
                          "use path")


@pytest.fixture(scope="module", autouse=True)
def _test_integrators():
    mi.register_integrator("coverage_scaled_path", lambda props: _ScaledPath(props))
    mi.register_integrator("coverage_refusing", lambda props: _Refusing(props))
    yield


def _spec(name, params, **kw):
    return expected.Spec(name, params, spp=64, **kw)


def test_scaled_path_fails_and_path_passes():
    for scale, outcome in ((1.1, outcomes.FAIL), (1.0, outcomes.PASS)):
        cell = matrix.run("bsdf:diffuse", _spec("path*%g" % scale, {"type": "coverage_scaled_path", "scale": scale}),
                          seed=budget.seed(SEED))
        assert cell.outcome == outcome, repr(cell)


def test_truncated_path_fails():
    spec = _spec("path(max_depth=2)", {"type": "coverage_scaled_path"}, row_params={"bsdf:diffuse": {"max_depth": 2}})
    cell = matrix.run("bsdf:diffuse", spec, seed=budget.seed(SEED))
    assert cell.outcome == outcomes.FAIL and cell.z < -4.5, repr(cell)


def test_refusals_are_recognised_by_their_message():
    right = _spec("refusing", {"type": "coverage_refusing"}, refused={"bsdf:diffuse": r"coverage_refusing: .*'diffuse'"})
    assert matrix.run("bsdf:diffuse", right).outcome == outcomes.REFUSED
    wrong = _spec("refusing", {"type": "coverage_refusing"}, refused={"bsdf:diffuse": r"'plastic'"})
    cell = matrix.run("bsdf:diffuse", wrong)
    assert cell.outcome == outcomes.FAIL and "not the expected refusal" in cell.failures[0], repr(cell)
    unexpected = matrix.run("bsdf:diffuse", _spec("refusing", {"type": "coverage_refusing"}))
    assert unexpected.outcome == outcomes.FAIL, repr(unexpected)


def test_a_slow_cell_fails(monkeypatch):
    monkeypatch.setattr(matrix, "SLOWNESS_LIMIT", 1e-3)
    cell = matrix.run("bsdf:diffuse", _spec("path", {"type": "coverage_scaled_path"}), seed=budget.seed(SEED))
    assert cell.outcome == outcomes.FAIL and any("the reference's" in f for f in cell.failures), repr(cell)


def test_a_slowness_exception_holds_for_its_row_only(monkeypatch):
    monkeypatch.setattr(matrix, "SLOWNESS_LIMIT", 1e-3)
    spec = _spec("path", {"type": "coverage_scaled_path"}, slowness={"bsdf:diffuse": (1e6, "a test")})
    assert matrix.run("bsdf:diffuse", spec, seed=budget.seed(SEED)).outcome == outcomes.PASS
    other = matrix.run("bsdf:roughplastic", spec, seed=budget.seed(SEED))
    assert other.outcome == outcomes.FAIL and any("the reference's" in f for f in other.failures), repr(other)
