"""The package as users install it: a wheel built from the checkout, installed into a
clean virtual environment outside the tree, with every ``mi-plugins`` sub-command run
from it, the coverage suite's refusals, and a user's test through the pytest plugin.

The wheel holds every package directory of the checkout (the plugin folders under
``mi_plugins``) and the package data; the test of the test: a list of the wheel's files
with one package left out is caught. Slow (a virtual environment, Mitsuba installed from
pip's cache, kernels compiled in a new process): one test.
"""
import glob
import os
import re
import subprocess
import sys
import zipfile

import pytest

from conftest import REPO

FOLDERS = {"mi_plugins": "mi_plugins", "integrators": "mi_plugins/integrators", "bsdfs": "mi_plugins/bsdfs",
           "emitters": "mi_plugins/emitters", "samplers": "mi_plugins/samplers"}

#: a user's own test through the installed pytest plugin (fixtures and the assertion)
USER_TEST = '''
from mi_plugins.verify.pytest_plugin import assert_matches_analytic


def test_path_matches_the_furnace(mi_variant, analytic_cases):
    assert_matches_analytic(analytic_cases("furnace_box"), {"type": "path"}, spp=4, runs=16)
'''


def expected_files():
    """The package files a wheel must hold (paths inside the wheel)."""
    out = set()
    for folder, target in FOLDERS.items():
        root = os.path.join(REPO, folder)
        for dp, dirs, files in os.walk(root):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            if "__init__.py" not in files and dp != os.path.join(REPO, "mi_plugins", "data"):
                continue
            for f in files:
                if f.endswith(".py") or os.path.basename(dp) == "data":
                    rel = os.path.relpath(os.path.join(dp, f), root).replace(os.sep, "/")
                    out.add(target + "/" + rel)
    return out


def missing(wheel_names):
    """The expected files the wheel lacks."""
    return sorted(expected_files() - set(wheel_names))


def run(args, cwd, env=None, timeout=900):
    out = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                         env=dict(os.environ, **(env or {})))
    assert out.returncode == 0, "%s\n%s\n%s" % (" ".join(map(str, args)), out.stdout[-3000:], out.stderr[-3000:])
    return out.stdout


def test_the_file_check_sees_a_missing_package():
    names = sorted(expected_files())
    assert names and missing(names) == []
    gone = [n for n in names if not n.startswith("mi_plugins/integrators/ray_bundle/")]
    assert missing(gone) and all(n.startswith("mi_plugins/integrators/ray_bundle/") for n in missing(gone))


@pytest.mark.slow
def test_an_installed_wheel_runs_every_sub_command(tmp_path):
    dist, venv, work = tmp_path / "dist", tmp_path / "venv", tmp_path / "work"
    work.mkdir()
    run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), REPO], cwd=str(tmp_path))
    wheel = glob.glob(str(dist / "mi_plugins-*.whl"))
    assert len(wheel) == 1, wheel
    with zipfile.ZipFile(wheel[0]) as z:
        assert missing(z.namelist()) == []
    run([sys.executable, "-m", "venv", str(venv)], cwd=str(tmp_path))
    py, cli = str(venv / "bin" / "python"), str(venv / "bin" / "mi-plugins")
    run([py, "-m", "pip", "install", "-q", wheel[0], "pytest"], cwd=str(tmp_path))
    # the installed package, not the checkout: outside the tree, no path to it
    where = run([py, "-c", "import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import mi_plugins; "
                           "print(mi_plugins.__file__)"], cwd=str(work))
    assert str(venv) in where and REPO not in where, where
    # one integrator's plain row on one case (the demo below renders every integrator of the
    # package; the other rows would add only kernels to compile)
    text = run([cli, "verify", "--quick", "--integrators", "qmc_lighttrace", "--scenes", "keller_cube"], cwd=str(work))
    assert "0 failed" in text, text[-2000:]
    text = run([cli, "verify", "--suite", "coverage", "--scenes", "medium:homogeneous", "medium:heterogeneous"],
               cwd=str(work))
    assert text.count("REFUSED") >= 10 and not re.search(r"^\s*FAIL\b", text, re.M), text[-2000:]
    scene = os.path.join(REPO, "configs", "keller_cube.xml")
    run([cli, "render", scene, "-o", str(work / "keller.exr"), "--spp", "4", "--passes", "2"], cwd=str(work))
    assert (work / "keller.exr").exists()
    run([py, "-c", "import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import mi_plugins\n"
                   "scene = mi.load_file(%r)\n"
                   "mi_plugins.solve(scene, {'type': 'qmc_lighttrace', 'samples': 2000, 'display': 'smooth'})"
                   ".save('keller.npz')" % scene], cwd=str(work))
    run([cli, "view", "keller.npz", "--scene", scene, "-o", "keller.html"], cwd=str(work))
    assert (work / "keller.html").stat().st_size > 1000
    run([cli, "demo", "--out", "demo", "--seconds", "0.3", "--resolution", "16", "--frames", "0", "--no-check"],
        cwd=str(work))
    assert glob.glob(str(work / "demo" / "*.png"))
    (work / "test_user.py").write_text(USER_TEST)
    text = run([py, "-m", "pytest", "-q", "-p", "no:cacheprovider", "test_user.py"], cwd=str(work))
    assert "1 passed" in text, text[-2000:]
