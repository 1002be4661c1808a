"""The pytest plugin (mi_plugins/verify/pytest_plugin.py, docs/pytest_plugin.md), run as a user
runs it: pytest in a fresh interpreter on a small project written into tmp_path.

``-p mi_plugins.verify.pytest_plugin`` loads the plugin from this checkout, and
PYTEST_DISABLE_PLUGIN_AUTOLOAD keeps an installed entry point (and any other installed
plugin) out of those sessions. The 3 % error is caught with margin: every passing check
here detects a relative error of 1.5 % (``power=0.015``), half the error it must see.
"""
import os
import re
import subprocess
import sys
import textwrap

from conftest import REPO
from budget import seed

#: a user's integrators: Mitsuba's path tracer wrapped in a Python integrator, times `scale`
INTEGRATORS = '''
import mitsuba as mi


def factory(scale=1.0):
    """Registers `scaled_path` (Mitsuba's path tracer, its radiance times `scale`); returns its dict."""
    class ScaledPath(mi.SamplingIntegrator):
        def __init__(self, props):
            super().__init__(props)
            self.scale = props.get("scale", 1.0)
            self.inner = mi.load_dict({"type": "path"})

        def sample(self, scene, sampler, ray, medium=None, active=True):
            L, valid, aovs = self.inner.sample(scene, sampler, ray, medium, active)
            return L * self.scale, valid, aovs

    mi.register_integrator("scaled_path", lambda props: ScaledPath(props))
    return {"type": "scaled_path", "scale": scale}


def wrong():
    """The same, 3 % too bright."""
    return factory(1.03)
'''


def project(tmp_path, files):
    """Write a project (``pytest.ini`` pins its root) and return its folder."""
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    for name, text in files.items():
        (tmp_path / name).write_text(textwrap.dedent(text))
    return tmp_path


def run_pytest(folder, *args):
    env = dict(os.environ, PYTEST_DISABLE_PLUGIN_AUTOLOAD="1",
               PYTHONPATH=os.pathsep.join([REPO] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    env.pop("PYTEST_ADDOPTS", None)
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "mi_plugins.verify.pytest_plugin", "-p", "no:cacheprovider",
                        *args], cwd=str(folder), env=env, capture_output=True, text=True, timeout=300)
    return r.returncode, r.stdout + r.stderr


def test_the_entry_point_is_declared_in_pyproject():
    path = os.path.join(REPO, "pyproject.toml")
    try:
        import tomllib
    except ImportError:  # Python < 3.11
        text = open(path).read()
        assert '[project.entry-points.pytest11]\nmi_plugins = "mi_plugins.verify.pytest_plugin"' in text
        return
    with open(path, "rb") as f:
        data = tomllib.load(f)
    assert data["project"]["entry-points"]["pytest11"] == {"mi_plugins": "mi_plugins.verify.pytest_plugin"}


def test_loading_the_plugin_costs_nothing_and_keeps_a_conftest_that_sets_the_variant(tmp_path):
    """A session that uses no fixture or option of the plugin imports no Mitsuba and sets no
    variant; a conftest like the package's own (set the variant, import mi_plugins) gets
    the full import with every plugin registered."""
    folder = project(tmp_path, {
        "conftest.py": """
            import sys
            LOADED_AT_CONFTEST = sorted(m for m in ("mitsuba", "drjit") if m in sys.modules)
            import mitsuba as mi
            mi.set_variant("llvm_ad_rgb")
            import mi_plugins
            """,
        "test_suite.py": """
            import sys
            import mitsuba as mi
            import mi_plugins
            import conftest

            def test_plugin_load_imported_no_mitsuba():
                assert conftest.LOADED_AT_CONFTEST == []

            def test_the_package_is_fully_imported():
                assert not mi_plugins._BARE
                assert mi_plugins.verify.pytest_plugin is sys.modules["mi_plugins.verify.pytest_plugin"]
                assert "stochastic_ray" in mi_plugins.registered["integrator"]
                mi.load_dict({"type": "stochastic_ray"})
            """})
    code, out = run_pytest(folder, "-v")
    assert code == 0, out
    assert "2 passed" in out, out


def test_the_helper_passes_a_correct_integrator_and_reports_a_3_percent_error(tmp_path):
    folder = project(tmp_path, {"myintegrators.py": INTEGRATORS, "test_example.py": """
        import pytest
        from mi_plugins.verify.pytest_plugin import assert_matches_analytic
        import myintegrators

        @pytest.mark.parametrize("analytic_case", ["furnace_box", "diffuse_sphere"], indirect=True)
        def test_correct(mi_variant, analytic_case):
            assert mi_variant == "llvm_ad_rgb"
            assert_matches_analytic(analytic_case, myintegrators.factory(), spp=64, runs=16, seed=%d, power=0.015)

        def test_wrong(analytic_cases):
            assert_matches_analytic(analytic_cases("furnace_box"), myintegrators.wrong(), spp=64, runs=16, seed=%d)

        def test_case_without_a_name(analytic_case):
            pass
        """ % (seed(41), seed(42))})
    code, out = run_pytest(folder, "-v", "--mi-resolution", "8")
    assert code == 1, out
    assert "test_correct[furnace_box] PASSED" in out and "test_correct[diffuse_sphere] PASSED" in out, out
    assert "test_wrong FAILED" in out, out
    # the harness's message, in pytest's output
    report = re.search(r"AssertionError: FAIL furnace_box x scaled_path\(scale=1.03\) \(spp 64 x 16 runs.*"
                       r"z = \+([0-9.]+), limit ([0-9.]+).*detects a relative bias of ([0-9.]+) %", out)
    assert report, out
    z, limit, detects = (float(v) for v in report.groups())
    assert detects <= 1.5 and z > 2 * limit, out
    assert re.search(r"image mean 1.0[23]\d* differs from exact 1 by", out), out
    assert "the analytic_case fixture needs a case name" in out and "1 error" in out, out


def test_the_documented_example_passes_without_a_conftest(tmp_path):
    """The test file of docs/pytest_plugin.md, as a user copies it."""
    with open(os.path.join(REPO, "docs", "pytest_plugin.md")) as f:
        example = re.search(r"```python\n(.*?)```", f.read(), re.S).group(1)
    assert len(example.strip().splitlines()) <= 13 and "def test_" in example
    code, out = run_pytest(project(tmp_path, {"test_my_integrator.py": example}), "-v", "--mi-resolution", "8")
    assert code == 0, out
    assert "test_my_integrator[furnace_box] PASSED" in out and "test_my_integrator[diffuse_sphere] PASSED" in out, out


def test_mi_integrator_collects_the_matrix_without_test_files(tmp_path):
    """`pytest --mi-integrator module:factory` in a folder with no test file and no conftest."""
    folder = project(tmp_path, {"myintegrators.py": INTEGRATORS})
    budget = ("--mi-cases", "furnace_box,diffuse_sphere", "--mi-resolution", "8", "--mi-spp", "64", "--mi-runs", "16",
              "--mi-power", "0.015", "-v", "-rA")
    code, out = run_pytest(folder, "--mi-integrator", "myintegrators:factory", "--mi-seed", str(seed(43)), *budget)
    assert code == 0, out
    assert "collected 2 items" in out, out
    assert "mi_analytic[furnace_box] PASSED" in out and "mi_analytic[diffuse_sphere] PASSED" in out, out
    assert "mi_analytic: scaled_path(scale=1.0)" in out, out  # the summary table

    code, out = run_pytest(folder, "--mi-integrator", "myintegrators:wrong", "--mi-seed", str(seed(44)), *budget)
    assert code == 1, out
    assert "mi_analytic[furnace_box] FAILED" in out and "mi_analytic[diffuse_sphere] FAILED" in out, out
    assert "FAIL furnace_box x scaled_path(scale=1.03)" in out and "image mean" in out, out
    assert "reproduce: pytest --mi-integrator 'myintegrators:wrong' --mi-cases furnace_box" in out, out


def test_mi_integrator_skips_the_cases_an_integrator_cannot_handle(tmp_path):
    """A plugin name; N/A cases are skipped with their reason, without rendering."""
    code, out = run_pytest(project(tmp_path, {}), "--mi-integrator", "ptracer", "--mi-cases", "mirror_sphere", "-rs")
    assert code == 0, out
    assert "1 skipped" in out and "N/A: a light tracer cannot connect light paths" in out, out
    code, out = run_pytest(tmp_path, "--mi-integrator", "no_such_plugin")
    assert code == 4 and 'Plugin "no_such_plugin" not found' in out, out
