"""End-to-end tests of `mi-plugins verify` and `mi-plugins render`."""
import json
import os
import re
import subprocess
import sys

import mitsuba as mi
import numpy as np
import pytest

from mi_plugins.app import exr

from conftest import REPO

import budget

CLI = [sys.executable, "-m", "mi_plugins"]


def run_cli(*args, timeout=600):
    return subprocess.run(CLI + list(args), capture_output=True, text=True, cwd=REPO, timeout=timeout)


def test_verify_subset_with_reports(tmp_path):
    r = run_cli("verify", "--quick", "--integrators", "path", "ptracer", "--scenes", "keller_cube",
                "mirror_sphere", "--report", str(tmp_path))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "PASS" in r.stdout and "N/A" in r.stdout and "light tracer cannot" in r.stdout
    assert "3 passed, 0 failed" in r.stdout
    data = json.load(open(tmp_path / "verify.json"))
    statuses = sorted(x["status"] for x in data["results"])
    assert statuses == ["N/A", "PASS", "PASS", "PASS"]
    assert "| keller_cube | path |" in open(tmp_path / "verify.md").read()


def _verify_in_process(monkeypatch, capsys, specs, *args):
    """`mi-plugins verify` in this process with the matrix's integrators replaced by
    ``specs``: (exit status, printed output)."""
    from mi_plugins.app import cli
    from mi_plugins.verify.analytic import matrix
    monkeypatch.setattr(matrix, "INTEGRATORS", specs)
    status = cli.main(["verify", "--quick"] + list(args))
    return status, capsys.readouterr().out


def test_verify_exit_status_and_known_failure_reporting(monkeypatch, capsys):
    """Exit status 0 when every check passes, is a documented known failure (XFAIL, or
    XPASS when the budget cannot see it) or not applicable; 1 on an unexpected failure."""
    from mi_plugins.verify.analytic.matrix import IntegratorSpec
    right = IntegratorSpec({"type": "path"}, quick_spp=4, quick_runs=16)
    # a deliberately wrong row: renders depth 3, compared with the untruncated value
    wrong = IntegratorSpec({"type": "path", "max_depth": 3}, quick_spp=4, quick_runs=16, exact_depth=-1)
    status, out = _verify_in_process(monkeypatch, capsys, {"right": right}, "--scenes", "keller_cube")
    assert status == 0 and "1 passed, 0 failed" in out
    status, out = _verify_in_process(monkeypatch, capsys, {"right": right, "wrong": wrong}, "--scenes", "keller_cube")
    assert status == 1 and "1 passed, 1 failed" in out and "FAIL keller_cube x wrong" in out
    wrong.known_failures = {"keller_cube": "a documented finding"}
    right.known_failures = {"keller_cube": "a finding this budget cannot see"}
    status, out = _verify_in_process(monkeypatch, capsys, {"right": right, "wrong": wrong}, "--scenes", "keller_cube")
    assert status == 0 and "0 passed, 0 failed, 1 known failures, 1 unexpected passes" in out
    assert re.search(r"XFAIL\s+keller_cube\s+wrong", out) and re.search(r"XPASS\s+keller_cube\s+right", out)


def test_verify_rows_of_the_package_integrators_pass():
    """The matrix rows of this package's integrators' variants (``name+variant``, quick
    budgets) on two cases; the plain rows run on the same cases from the installed wheel
    (tests/test_wheel.py)."""
    from mi_plugins.verify.analytic import matrix
    rows = [name for name in matrix.INTEGRATORS if "+" in name and name.split("+")[0] in (
        "stochastic_ray", "ray_bundle", "qmc_lighttrace")]
    assert len(rows) >= 2
    results = matrix.run(rows, ["keller_cube", "furnace_sphere_mesh"], quick=True, seed=budget.seed(2))
    assert all(r.status == "PASS" for r in results), "\n".join(repr(r) for r in results if r.status != "PASS")


def test_verify_unknown_scene_is_one_clear_line():
    r = run_cli("verify", "--scenes", "nope")
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "unknown scene nope" in r.stderr


def test_render_writes_exr_with_metadata(tmp_path):
    out = tmp_path / "keller.exr"
    r = run_cli("render", os.path.join("configs", "keller_cube.xml"), "-o", str(out), "--spp", "16",
                "--seed", "3", "-D", "integrator=ptracer")
    assert r.returncode == 0, r.stderr
    image, meta = exr.read(str(out))
    assert image.shape == (32, 32, 3) and np.all(np.isfinite(image))
    assert abs(image.mean() - 0.5) < 0.05
    assert meta["spp"] == "16" and meta["seed"] == "3" and float(meta["seconds"]) > 0
    assert meta["integrator"] == "ptracer"
    assert meta["version"]


def test_render_errors_are_one_line(tmp_path):
    r = run_cli("render", "missing.xml", "-o", str(tmp_path / "x.exr"))
    assert r.returncode == 2 and "does not exist" in r.stderr and r.stderr.count("\n") == 1
    r = run_cli("render", os.path.join("configs", "keller_cube.xml"), "-o", str(tmp_path / "x.exr"),
                "-D", "integrator=no_such_plugin")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "no_such_plugin" in r.stderr
    r = run_cli("render", os.path.join("configs", "keller_cube.xml"), "-o", str(tmp_path / "x.exr"),
                "--spp", "0")
    assert r.returncode == 2 and "--spp 0" in r.stderr


def test_interrupted_render_keeps_finished_passes():
    import mitsuba as mi
    from mi_plugins.verify import analytic
    from mi_plugins.app import passes
    scene = analytic.keller_cube(resolution=8).scene("path")

    def stop_after_two(done, total):
        if done == 2:
            raise KeyboardInterrupt

    res = passes.render_in_passes(scene, spp=8, passes=4, callback=stop_after_two)
    assert res.interrupted and res.passes_done == 2 and res.spp_done == 4
    assert abs(res.image.mean() - 0.5) < 0.05


def test_ctrl_c_writes_the_finished_passes(tmp_path):
    import signal
    import time
    out = tmp_path / "partial.exr"
    proc = subprocess.Popen(CLI + ["render", os.path.join("configs", "furnace_sierpinski.xml"), "-o", str(out),
                                   "--spp", "100000", "--passes", "1000", "-D", "integrator=ptracer"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    # wait until tqdm reports a finished pass, then press Ctrl-C
    buf = ""
    while time.time() < deadline and "/1000" not in buf.replace(" 0/1000", ""):
        buf += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stdout + stderr
    assert "interrupted after" in stdout
    image, meta = exr.read(str(out))
    done, total = (int(v) for v in meta["passes"].split("/"))
    assert 1 <= done < total == 1000
    assert int(meta["spp"]) == 100 * done
    assert abs(image.mean() - 1.0) < 0.2 and np.all(np.isfinite(image))


@pytest.mark.parametrize("integrator", [{"type": "stochastic_ray", "iterations": 40, "burn_in": 8},
                                        {"type": "ray_bundle", "iterations": 40, "burn_in": 8, "resolution": 32,
                                         "chains": 1, "first_shot": False, "average_diffuse": False}],
                         ids=["stochastic_ray", "ray_bundle"])
def test_interrupted_iterative_render_keeps_finished_iterations(integrator):
    """Ctrl-C (here: raised by the progress hook) inside the second pass of an iterative
    integrator keeps pass 1 and the finished iterations of pass 2, weighted by their share."""
    from mi_plugins.verify import analytic
    from mi_plugins.app import passes
    from mi_plugins.base import errors
    from mi_plugins.render import pass_seeds
    scene = analytic.furnace(0.5, 0.5, "box", resolution=8).scene(integrator)
    integ = scene.integrator()
    per_pass = integ.iteration_count(1)
    seen = []

    def on_pass(done, total):
        seen.append(done)
        original = integ.progress_callback

        def stop_midway(finished, total_iterations):
            original(finished, total_iterations)
            if finished == 24:
                raise KeyboardInterrupt
        integ.progress_callback = stop_midway

    res = passes.render_in_passes(scene, spp=2, passes=2, callback=on_pass)
    assert res.interrupted and res.passes_done == 1 and seen == [1]
    assert res.iterations == 2 * per_pass and res.iterations_done == per_pass + 24
    assert integ.progress.averaged_fraction == pytest.approx((24 - 8) / (per_pass - 8))
    assert integ.progress_callback is None
    assert np.all(np.isfinite(res.image)) and abs(res.image.mean() - 1.0) < 0.1


@pytest.mark.parametrize("integrator", [{"type": "stochastic_ray", "iterations": 40, "burn_in": 8},
                                        {"type": "ray_bundle", "iterations": 40, "burn_in": 8, "resolution": 16,
                                         "chains": 4, "first_shot": False, "average_diffuse": False}],
                         ids=["stochastic_ray", "ray_bundle"])
def test_interrupted_pass_weighting_matches_separate_renders(integrator):
    """The image of a render interrupted in its second pass equals, to 1e-6, the
    weighted average of the two passes rendered separately with the same seeds:
    (pass 1 x spp 1 + partial pass 2 x spp 2 x share) / (spp 1 + spp 2 x share), where
    share is the fraction of pass 2's averaged iterations finished (16 of 32)."""
    from mi_plugins.verify import analytic
    from mi_plugins.app import passes
    from mi_plugins.base import errors
    from mi_plugins.render import pass_seeds
    scene = analytic.furnace(0.5, 0.5, "box", resolution=8).scene(integrator)
    integ = scene.integrator()
    seed = budget.seed(3)

    def on_pass(done, total):
        def stop_at_24(finished, total_iterations):
            if finished == 24:
                raise KeyboardInterrupt
        integ.progress_callback = stop_at_24

    res = passes.render_in_passes(scene, spp=3, passes=2, seed=seed, callback=on_pass)
    assert res.interrupted and res.passes_done == 1 and res.partial_pass == pytest.approx(0.5)
    first = np.array(mi.render(scene, spp=2, seed=seed * 100003), dtype=np.float64)
    integ.progress_callback = lambda finished, total_iterations: finished < 24
    second = np.array(mi.render(scene, spp=1, seed=seed * 100003 + 1), dtype=np.float64)
    integ.progress_callback = None
    share = integ.progress.averaged_fraction
    assert share == pytest.approx(0.5)
    expected = (first * 2 + second * 1 * share) / (2 + 1 * share)
    assert np.allclose(res.image, expected, rtol=1e-6, atol=1e-6), np.abs(res.image - expected).max()
    assert not np.allclose(res.image, first, rtol=1e-3)


def test_ctrl_c_keeps_the_finished_iterations_of_stochastic_iteration(tmp_path):
    """A real SIGINT during `mi-plugins render` with an iterative integrator: the progress
    bar counts iterations and the EXR holds the finished ones."""
    import signal
    import time
    out = tmp_path / "partial.exr"
    proc = subprocess.Popen(CLI + ["render", os.path.join("configs", "furnace_box.xml"), "-o", str(out),
                                   "--spp", "1000", "--passes", "1000", "-D", "integrator=stochastic_ray"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    buf = ""     # default stochastic_ray: 32 iterations per pass -> bar total 32000
    # wait until the first pass (32 iterations) is done, so there is something to keep
    while time.time() < deadline and max([0] + [int(v) for v in re.findall(r"(\d+)/32000", buf)]) < 40:
        buf += os.read(proc.stderr.fileno(), 4096).decode(errors="replace")
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stdout + stderr
    assert "interrupted after" in stdout and "iterations" in stdout
    image, meta = exr.read(str(out))
    done, total = (int(v) for v in meta["iterations"].split("/"))
    assert 40 <= done < total == 32000
    assert abs(image.mean() - 1.0) < 0.3 and np.all(np.isfinite(image))


# --- in-process `mi-plugins render` on an 8x8 copy of a config -----------------------

def tiny_config(tmp_path, config="keller_cube.xml", size=8):
    """``configs/<config>`` with a ``size`` x ``size`` film, written into ``tmp_path``."""
    text = open(os.path.join(REPO, "configs", config)).read()
    text = text.replace('value="32"', 'value="%d"' % size)
    text = text.replace('"meshes/', '"%s/' % os.path.join(REPO, "configs", "meshes"))
    path = tmp_path / config
    path.write_text(text)
    return str(path)


def render_in_process(capsys, *args):
    """`mi-plugins render ARGS` in this process: (exit status, stdout, stderr)."""
    from mi_plugins.app import cli
    status = cli.main(["render"] + [str(a) for a in args])
    out, err = capsys.readouterr()
    return status, out, err


def error_line(err):
    """The error message of a failed command: exactly one line on stderr (a progress bar
    that was showing is cleared, carriage returns only)."""
    assert err.count("\n") == 1 and err.endswith("\n"), repr(err)
    line = err.rsplit("\r", 1)[-1]
    assert line.startswith("mi-plugins: error: "), repr(err)
    return line


@pytest.fixture
def no_render(monkeypatch):
    """Fail the test if `mi-plugins render` starts loading or rendering the scene."""
    from mi_plugins.app import passes
    from mi_plugins.base import errors
    from mi_plugins.render import pass_seeds

    def refuse(*args, **kwargs):
        raise AssertionError("rendering started")
    monkeypatch.setattr(mi, "load_file", refuse)
    monkeypatch.setattr(passes, "render_in_passes", refuse)


def _non_mesh_error():
    from mi_plugins.patches.meshtable import NonMeshShapeError
    return NonMeshShapeError("stochastic_ray: shape 'sphere' (Sphere) is not a triangle mesh")


def _parameter_error():
    from mi_plugins.base.params import parameter_error
    return parameter_error("stochastic_ray", [("iterations", 0)], "1 or more")


@pytest.mark.parametrize("error,message", [
    (_non_mesh_error, "stochastic_ray: shape 'sphere' (Sphere) is not a triangle mesh"),
    (_parameter_error, "stochastic_ray: parameter iterations=0 is invalid; valid range: 1 or more")],
    ids=["non_mesh_shape", "parameter"])
def test_render_error_prints_the_cause_not_the_drjit_wrapper(tmp_path, capsys, monkeypatch, error, message):
    """An exception raised while a Python integrator renders reaches the caller of
    mi.render wrapped into a generic Dr.Jit error ("error while performing a custom
    differentiable operation"): the command reports the exception's own message, in one
    line, with the progress bar cleared, and writes nothing."""
    from mi_plugins.integrators.stochastic_ray import StochasticRayIntegrator

    def render_frame(self, frame):
        raise error()
    monkeypatch.setattr(StochasticRayIntegrator, "render_frame", render_frame)
    status, out, err = render_in_process(capsys, tiny_config(tmp_path), "-o", tmp_path / "x.exr", "--spp", 1,
                                         "-D", "integrator=stochastic_ray")
    assert status == 2 and error_line(err) == "mi-plugins: error: %s\n" % message
    assert not (tmp_path / "x.exr").exists()


def test_render_refuses_a_scene_sampler_without_samples(tmp_path):
    """0 samples per pixel makes Mitsuba die with SIGFPE: refused before rendering."""
    r = run_cli("render", tiny_config(tmp_path), "-o", str(tmp_path / "x.exr"), "-D", "spp=0", timeout=120)
    assert r.returncode == 2, r.stderr
    line = error_line(r.stderr)
    assert "sample_count=0" in line and "valid range: 1 or more" in line
    assert not (tmp_path / "x.exr").exists()


def test_render_refuses_a_seed_mitsuba_cannot_take(tmp_path, capsys):
    status, out, err = render_in_process(capsys, tiny_config(tmp_path), "-o", tmp_path / "x.exr", "--seed", -1)
    assert status == 2 and "seed=-1 is out of range; valid range: 0 .. 42948 (with 8 passes)" in error_line(err)


@pytest.mark.parametrize("integrator", ["path", "qmc_lighttrace"])
def test_render_metadata_names_the_integrator_plugin(tmp_path, capsys, integrator):
    out = tmp_path / "x.exr"
    status, stdout, err = render_in_process(capsys, tiny_config(tmp_path), "-o", out, "--spp", 2, "--passes", 1,
                                            "-D", "integrator=%s" % integrator)
    assert status == 0, err
    image, meta = exr.read(str(out))
    assert image.shape == (8, 8, 3) and meta["integrator"] == integrator


@pytest.mark.parametrize("name,magic", [("x.png", b"\x89PNG\r\n\x1a\n"), ("x.JPG", b"\xff\xd8\xff")])
def test_render_writes_png_and_jpeg_by_extension(tmp_path, capsys, name, magic):
    out = tmp_path / name
    status, stdout, err = render_in_process(capsys, tiny_config(tmp_path), "-o", out, "--spp", 16, "--passes", 2)
    assert status == 0, err
    assert out.read_bytes()[:len(magic)] == magic
    image = np.array(mi.Bitmap(str(out)))
    assert image.shape == (8, 8, 3) and image.dtype == np.uint8
    # radiance 0.5 everywhere: sRGB 0.5 is 188 of 255 (a linear 8-bit image would hold 128)
    assert abs(image.mean() - 188) < 20


def test_render_refuses_an_unknown_output_extension_before_rendering(tmp_path, capsys, no_render):
    status, out, err = render_in_process(capsys, tiny_config(tmp_path), "-o", tmp_path / "x.tif")
    line = error_line(err)
    assert status == 2 and "'.tif'" in line and "valid extensions: .exr, .png, .jpg, .jpeg" in line


def test_render_checks_the_output_directory_before_rendering(tmp_path, capsys, no_render):
    scene = os.path.join(REPO, "configs", "keller_cube.xml")
    status, out, err = render_in_process(capsys, scene, "-o", tmp_path / "missing" / "x.exr")
    assert status == 2 and "directory '%s' does not exist" % (tmp_path / "missing") in error_line(err)
    (tmp_path / "file").write_text("")
    status, out, err = render_in_process(capsys, scene, "-o", tmp_path / "file" / "x.exr")
    assert status == 2 and "is not a directory" in error_line(err)
    status, out, err = render_in_process(capsys, scene, "-o", tmp_path)
    assert status == 2 and "valid extensions" in error_line(err)
    (tmp_path / "d.exr").mkdir()
    status, out, err = render_in_process(capsys, scene, "-o", tmp_path / "d.exr")
    assert status == 2 and "is a directory" in error_line(err)


def test_verify_suite_scenes_runs_the_conformance_suite(tmp_path, capsys):
    """`verify --suite scenes` runs the conformance suite (here one cheap combination)
    and writes its reports; --list names its integrators and scenes."""
    from mi_plugins.app import cli
    assert cli.main(["verify", "--suite", "scenes", "--list"]) == 0
    assert "no_emitters" in capsys.readouterr().out
    status = cli.main(["verify", "--suite", "scenes", "--scenes", "no_emitters", "--integrators", "stochastic_ray",
                       "--quick", "--report", str(tmp_path)])
    out = capsys.readouterr().out
    assert status == 0 and "no_emitters" in out and "PASS" in out
    assert (tmp_path / "conformance.json").exists()
