import gc
import json
import os
import subprocess
import sys

import pytest

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import drjit as dr  # noqa: E402

# The suite builds every scene's setup itself: its tests of the tests replace the code that
# builds it, which a disk cache of earlier runs would skip (tests/test_setup_cache.py turns
# the cache on where it is the subject).
os.environ["MI_PLUGINS_SETUP_CACHE"] = "off"

import mi_plugins  # noqa: E402,F401  (registers the plugins)
from mi_plugins.verify.analytic import harness  # noqa: E402

import budget  # noqa: E402
import extended_tier  # noqa: E402
from budget import seed  # noqa: E402,F401  (re-exported for the tests)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# Every comparison of the harness is recorded (power rule, false-failure budget), and
# every harness render is shifted by the seed offset (MI_PLUGINS_SEED_OFFSET).
harness.OBSERVERS.append(budget.observe)
_render_runs = harness.render_runs


def _render_runs_with_offset(scene, spp, runs, seed):
    return _render_runs(scene, spp, runs, budget.seed(seed))


harness.render_runs = _render_runs_with_offset


def furnace_rmse(integrator, seeds, resolution, geometry="box"):
    """RMS over ``seeds`` of the per-image RMSE of ``integrator`` (a plugin dict) on the
    furnace ``geometry`` (albedo 0.5, emission 0.5: radiance 1 everywhere), one render
    per seed."""
    from mi_plugins.verify import analytic
    import numpy as np
    case = analytic.furnace(0.5, 0.5, geometry, resolution=resolution)
    scene = case.scene(integrator)
    exact = case.expected()
    errs = [np.sqrt(np.mean((np.array(mi.render(scene, spp=1, seed=s)) - exact) ** 2)) for s in seeds]
    return float(np.sqrt(np.mean(np.square(errs))))


def scalar_variant_refusal(plugin_type):
    """Output of loading ``plugin_type`` under the scalar_rgb variant in a fresh
    interpreter: (refused, output). The plugins are registered for scalar_rgb anyway
    (bypassing mi_plugins.register(), which refuses the variant first), so that the
    plugin's own check in its constructor is what refuses."""
    r = run_python("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import mi_plugins\n"
                   "from mi_plugins import registry\n"
                   "mi.set_variant('scalar_rgb'); registry.register_all('scalar_rgb')\n"
                   "try:\n    mi.load_dict({'type': '%s'})\n    print('LOADED')\n"
                   "except Exception as e:\n    print('ERR', e)" % plugin_type)
    return ("ERR" in r.stdout and "LOADED" not in r.stdout), r.stdout + r.stderr


def run_python(code, env=None, cwd=None):
    """Run a snippet in a fresh interpreter (variant state is process-global)."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full_env,
                          cwd=cwd or REPO, timeout=300)


@pytest.fixture(autouse=True)
def _primary_variant():
    if mi.variant() != "llvm_ad_rgb":
        mi.set_variant("llvm_ad_rgb")
        mi_plugins.register()
    yield


@pytest.fixture(autouse=True)
def _collect_scenes(request):
    """Free the scenes a test leaves in reference cycles or in the package's caches of the
    last scene (``mi_plugins.release``) right after it: Dr.Jit traces the
    methods of every live plugin instance in every later render (docs/findings.md), so
    uncollected scenes make the rest of the suite slower and slower (measured: a 0.4 s
    render took 2.7-12 s with 15 uncollected scenes alive). Tests marked ``renders_nothing``
    (plugins loaded, no render) leave it to their module's end: a full collection late in a
    worker's life costs 15 ms, and tests/test_parameters.py's 1 902 tests spent 28 s in it."""
    yield
    if request.node.get_closest_marker("renders_nothing") is None:
        mi_plugins.release()            # (the package's caches of the test's last scene, then gc.collect())


@pytest.fixture(autouse=True)
def _power_rule(request):
    """Names the running test for the statistics records; a passing harness check
    without the power the rule asks for fails the test (at teardown)."""
    budget._current["test"] = request.node.nodeid
    yield
    budget._current["test"] = None
    violations = budget.power_violations(request.node.nodeid)
    if violations:
        pytest.fail("power rule (tests/budget.py):\n  " + "\n  ".join(violations), pytrace=False)


#: test files run first, in this order: the package's Dr.Jit integrators trace Python code
#: every iteration, and in a long process Dr.Jit's per-operation cost grows (measured: the
#: same ray_bundle test 14 s alone, 120 s at the end of the suite); Mitsuba's C++
#: integrators, which the other files mostly use, are not affected
FIRST = ("test_ray_bundle.py", "test_stochastic_ray.py", "test_qmc_lighttrace.py", "test_textured_lights.py",
         "test_core.py", "test_conformance.py", "test_cli.py")


#: the extended tier: the tests marked ``extended`` (the coverage and conformance cells
#: beyond those their files choose for every run) and those tests/extended_tier.py lists;
#: ``make test`` leaves them out, ``make test-extended`` (pytest --extended) runs every test
def pytest_addoption(parser):
    parser.addoption("--extended", action="store_true", default=False,
                     help="run the extended tier too (docs/testing.md)")


def pytest_configure(config):
    config.addinivalue_line("markers", "extended: a test of the extended tier (make test-extended)")


def pytest_collection_finish(session):
    """Everything alive after collection (modules, test items, their parameters) lives
    until the end: moved out of the garbage collector's sight, so that the collection
    after every test (``_collect_scenes``) only looks at what the tests made (measured:
    tests/test_parameters.py, 1882 tests, 105 s -> 4.7 s in one process)."""
    gc.collect()
    gc.freeze()


#: seconds each test file takes on 2 cores (setup, calls and teardowns; a clean checkout,
#: measured); the summary reports every file over its budget and the total against
#: TOTAL_BUDGET. A file not listed has DEFAULT_FILE_BUDGET.
TIME_BUDGET = os.path.join(REPO, "tests", "data", "time_budget.json")
DEFAULT_FILE_BUDGET = 30.0
_file_seconds = {}


def read_budgets():
    """({test file as in a node id: its budget in seconds}, total budget) of TIME_BUDGET
    (no files and 15 minutes where it cannot be read)."""
    try:
        with open(TIME_BUDGET) as f:
            table = json.load(f)
    except (OSError, ValueError):
        table = {}
    return ({k: float(v) for k, v in table.get("files", {}).items()}, float(table.get("total", 15 * 60)))


def file_of(nodeid):
    """The test file of a node id (its budget's key)."""
    return nodeid.split("::", 1)[0]


def pytest_collection_modifyitems(session, config, items):
    rank = {name: k for k, name in enumerate(FIRST)}
    key = lambda item: rank.get(os.path.basename(str(item.fspath)), len(FIRST))
    if os.environ.get("PYTEST_XDIST_WORKER"):
        # under pytest-xdist with a file per process (``make test``: --dist loadfile
        # --no-loadscope-reorder) the files are handed out in this order: the longest first,
        # so that the two processes end together (one 680 s file last would leave a core idle)
        budgets = read_budgets()[0]
        key = lambda item, first=key: (-budgets.get(file_of(item.nodeid), DEFAULT_FILE_BUDGET), first(item))
    items.sort(key=key)
    for item in items:
        if extended_tier.extended(item.nodeid):
            item.add_marker(pytest.mark.extended)
    if config.getoption("--extended") or os.environ.get("MI_PLUGINS_EXTENDED"):
        return
    left = [item for item in items if item.get_closest_marker("extended")]
    if left:
        config.hook.pytest_deselected(items=left)
        kept = set(map(id, left))
        items[:] = [item for item in items if id(item) not in kept]


#: MI_PLUGINS_KERNEL_LOG=FILE: after every test, append the kernels it compiled (neither in
#: the process's cache nor on disk) and their compile seconds to FILE (per worker): which
#: tests pay the compilation of a fresh machine
KERNEL_LOG = os.environ.get("MI_PLUGINS_KERNEL_LOG")
if KERNEL_LOG:
    dr.set_flag(dr.JitFlag.KernelHistory, True)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if KERNEL_LOG:
        dr.kernel_history()
    yield
    if KERNEL_LOG:
        compiled = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT
                    and not k.get("cache_hit") and not k.get("cache_disk")]
        seconds = sum(float(k.get("backend_time", 0.0)) + float(k.get("codegen_time", 0.0)) for k in compiled) / 1000
        with open(KERNEL_LOG, "a") as f:
            f.write("%s\t%d\t%.3f\n" % (item.nodeid, len(compiled), seconds))


def pytest_runtest_logreport(report):
    """Sums each file's seconds; with MI_PLUGINS_TIMES=FILE also appends every test phase's
    seconds to FILE (node id, phase, seconds, outcome; written once, by the controller
    under pytest-xdist): the measurements behind tests/data/time_budget.json."""
    name = file_of(report.nodeid)
    _file_seconds[name] = _file_seconds.get(name, 0.0) + float(getattr(report, "duration", 0.0))
    if os.environ.get("MI_PLUGINS_TIMES") and not os.environ.get("PYTEST_XDIST_WORKER"):
        with open(os.environ["MI_PLUGINS_TIMES"], "a") as f:
            f.write("%s\t%s\t%.3f\t%s\n" % (report.nodeid, report.when, report.duration, report.outcome))


def time_report(seconds):
    """Lines of the per-file time report: the files over their budget, and the total."""
    budgets, total_budget = read_budgets()
    over = [(name, t, float(budgets.get(name, DEFAULT_FILE_BUDGET))) for name, t in sorted(seconds.items())
            if t > float(budgets.get(name, DEFAULT_FILE_BUDGET))]
    total = sum(seconds.values())
    lines = ["time: %.0f s in test files (budget %.0f s%s)" % (total, total_budget,
                                                            ", OVER" if total > total_budget else "")]
    lines += ["time: %s took %.1f s, over its budget of %.0f s (%s)" % (n, t, b, os.path.relpath(TIME_BUDGET, REPO))
              for n, t, b in over]
    return lines


def pytest_terminal_summary(terminalreporter):
    for line in budget.summary():
        terminalreporter.write_line(line)
    for line in time_report(_file_seconds):
        terminalreporter.write_line(line)


# With pytest-xdist (``-n 2``), each worker process records its own statistical checks;
# the controller collects them when a worker finishes, so the summary and the statistics
# log cover the whole run.
def pytest_sessionfinish(session):
    if hasattr(session.config, "workeroutput"):
        session.config.workeroutput["budget_records"] = json.dumps(budget._records)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    records = getattr(node, "workeroutput", {}).get("budget_records")
    if records:
        budget._records.extend(json.loads(records))
