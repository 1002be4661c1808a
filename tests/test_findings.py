"""The standalone reproducers of the findings of docs/findings.md (docs/findings/*.py): every one
compiles, needs only mitsuba/drjit/numpy and the standard library, carries a complete
report in its docstring and is listed in docs/findings/README.md; the fastest run end
to end (a few seconds) and still reproduce their finding."""
import ast
import os
import py_compile
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FINDINGS = os.path.join(ROOT, "docs", "findings")
SCRIPTS = sorted(f for f in os.listdir(FINDINGS) if f.endswith(".py"))
ALLOWED = {"mitsuba", "drjit", "numpy", "gc", "os", "subprocess", "sys", "tempfile", "time"}


def test_there_are_reproducers():
    assert len(SCRIPTS) >= 12, SCRIPTS


@pytest.mark.parametrize("name", SCRIPTS)
def test_reproducer_compiles_and_is_standalone(name, tmp_path):
    path = os.path.join(FINDINGS, name)
    py_compile.compile(path, cfile=str(tmp_path / (name + "c")), doraise=True)
    with open(path) as f:
        tree = ast.parse(f.read())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add((node.module or "").split(".")[0])
    assert imported <= ALLOWED, "%s imports %s" % (name, sorted(imported - ALLOWED))
    doc = ast.get_docstring(tree)
    for section in ("Expected", "Measured", "Cause", "Suggested fix", "Run: `python docs/findings/%s`" % name):
        assert section in doc, "%s: the docstring has no %r" % (name, section)
    assert "PASTE-OUTPUT" not in doc
    if "mitsuba" in imported:
        assert "Versions: Mitsuba 3.9.1, Dr.Jit 1.5.0" in doc and "Mitsuba 3.9.1, Dr.Jit 1.5.0, llvm_ad_rgb" in doc, name


@pytest.mark.parametrize("name", SCRIPTS)
def test_reproducer_is_listed_in_the_index(name):
    with open(os.path.join(FINDINGS, "README.md")) as f:
        assert "[%s](%s)" % (name, name) in f.read()


def run(name):
    out = subprocess.run([sys.executable, os.path.join(FINDINGS, name)], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


UPDATE = " (if a new Mitsuba fixed this, update docs/findings.md and docs/findings)"


def test_spectra_reproducer_runs_and_still_reproduces():
    out = run("rgb_variant_spectra_fail_at_render.py")
    assert "irregular           load: OK; render: raises RuntimeError: [IrregularSpectrum] " \
           "IrregularSpectrum::eval(): not implemented!" in out, out + UPDATE
    assert "blackbody           load: OK; render: raises" in out, out + UPDATE
    assert "spectrum (control)  load: OK; render: renders" in out, out


def test_poisoning_reproducer_runs_and_still_reproduces():
    out = run("failed_render_poisons_next.py")
    lines = dict(line.split(".", 1) for line in out.splitlines() if line[:2].rstrip(".").isdigit())
    assert lines["1"].endswith("renders") and lines["6"].endswith("renders"), out
    assert "raises: [BlackBodySpectrum]" in lines["3"] and "raises: [BlackBodySpectrum]" in lines["8"], out + UPDATE
    assert lines["9"].endswith("renders") and lines["10"].endswith("renders"), out


def test_flip_normals_reproducer_runs_and_still_reproduces():
    out = run("area_textured_flip_normals_nee.py")
    rows = {tuple(line.split()[:2]): line.split() for line in out.splitlines()
            if line.split()[:1] in (["rectangle"], ["flipped"], ["cube"]) and len(line.split()) == 10}
    assert len(rows) == 7, out
    for radiance in ("rgb", "checkerboard", "bitmap"):
        assert abs(float(rows["rectangle", radiance][-1])) < 4.5, out        # unflipped: right
    assert abs(float(rows["flipped", "rgb"][-1])) < 4.5, out
    for radiance in ("checkerboard", "bitmap"):
        assert float(rows["flipped", radiance][-2]) < 0.05, out + UPDATE     # flipped, textured: the light is lost
    assert float(rows["cube", "bitmap"][-1]) < -4.5, out + UPDATE
    assert "of eval_parameterization [0, 1, 0], of a ray hit [0, -1, 0]" in out, out + UPDATE


def test_tracing_abort_reproducer_runs_and_still_reproduces():
    out = run("plugin_made_while_tracing_aborts.py")
    assert "uv scene built while tracing: exit code" in out and "redefinition" in out, out + UPDATE
    assert "uv scene built before tracing: renders" in out, out


def test_roughdielectric_reproducer_runs_and_still_reproduces():
    out = run("roughdielectric_sample_pdf.py")
    blocks = {}
    for line in out.splitlines():
        if line.startswith("cos_i "):
            key = line.split()[1]
            blocks[key] = [line]
        elif line.startswith("   ") and blocks:
            blocks[key].append(line)
    assert set(blocks) == {"+0.90", "+0.50", "-0.90", "-0.70", "-0.50", "-0.40"}, out
    for key in ("-0.70", "-0.50", "-0.40"):      # inside the glass, beyond the critical angle
        first, chi2, estimates = blocks[key]
        assert "side: all of weight 0" in first and ", all on the other side" in first, out + UPDATE
        assert "weight != 0 accepted" in chi2 and "all samples rejected" in chi2, out + UPDATE
        z = float(estimates.split("E[eval / bs.pdf]")[1].split("z ")[1].split(")")[0])
        assert z > 4, out + UPDATE
    first, chi2, estimates = blocks["+0.90"]    # the control: nothing crosses the surface
    assert "(0) lie on the other lobe's side" in first and "all samples accepted" in chi2, out
    weight_z = float(estimates.split("E[weight]")[1].split("z ")[1].split(")")[0])
    assert abs(weight_z) < 4, out
