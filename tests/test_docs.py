"""The documentation: the plugin reference (docs/reference.md) is generated from the plugins' class
docstrings and up to date; every docstring table lists exactly the parameters its plugin
reads; code and docs speak of the project only."""
import os
import re
import subprocess
import sys

import pytest

from mi_plugins.app import reference
from test_parameters import TABLE

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_the_reference_is_generated_from_the_docstrings():
    with open(os.path.join(ROOT, "docs", "reference.md")) as f:
        text = f.read()
    assert reference.readme_block(text) == reference.markdown(), "run `python3 docs/generate_reference.py`"


def test_the_generator_script_checks_staleness():
    out = subprocess.run([sys.executable, os.path.join(ROOT, "docs", "generate_reference.py"), "--check"],
                         capture_output=True, text=True)
    assert out.returncode == 0 and "up to date" in out.stdout, out.stderr
    stale = reference.BEGIN + "\nold text\n" + reference.END
    assert reference.readme_block(stale) != reference.markdown()
    assert reference.readme_block(reference.update_readme(stale)) == reference.markdown()


@pytest.mark.parametrize("kind, name, cls", reference.plugin_classes(), ids=lambda x: x if isinstance(x, str) else "")
def test_every_plugin_documents_exactly_the_parameters_it_reads(kind, name, cls):
    """The docstring table against the bad-parameter table of tests/test_parameters.py,
    which a test checks against the parameters the plugin actually reads."""
    rows = reference.parameter_rows(cls.__doc__ or "")
    assert rows, "%s: no '.. pluginparameters::' table in the class docstring" % name
    assert [r[0] for r in rows] and set(r[0] for r in rows) == set(TABLE[name]), name
    section = reference._section("X", cls.__doc__)
    assert section.startswith("### X `%s` (" % name), section[:80]
    assert "```python" in section or "```xml" in section, "%s: no example" % name


def test_a_malformed_table_row_is_refused():
    doc = """T (``x``)\n---------\n\n.. pluginparameters::\n\n * - a\n   - int\n   - 1\n"""
    with pytest.raises(ValueError, match="expected 4 cells"):
        reference.parameter_rows(doc)


SOURCES = ("mi_plugins", "integrators", "bsdfs", "emitters", "samplers", "tests", "benchmarks", "docs", "configs")
FORBIDDEN = re.compile(r"\bissues? #?\d+\b|\.\./shared|/work/|github\.com/[^ ]*/issues/\d+", re.I)


def test_code_and_docs_speak_of_the_project_only():
    """No issue numbers and no paths outside the repository in code or docs."""
    offenders = []
    paths = [os.path.join(ROOT, "README.md")]
    for folder in SOURCES:
        for base, _, files in os.walk(os.path.join(ROOT, folder)):
            paths += [os.path.join(base, f) for f in files if f.endswith((".py", ".md", ".xml", ".txt"))]
    for path in paths:
        with open(path, errors="replace") as f:
            for number, line in enumerate(f, 1):
                if FORBIDDEN.search(line) and "FORBIDDEN" not in line:
                    offenders.append("%s:%d: %s" % (os.path.relpath(path, ROOT), number, line.strip()[:100]))
    assert not offenders, "\n".join(offenders)
