"""The extended tier's list (tests/extended_tier.py) names tests that exist, and leaves at
least one case of every parametrized test it names in every test run."""
import collections
import os
import re

import extended_tier
from conftest import REPO, run_python


def _collected():
    """{"file::test": [case ids]} of the files the list names, as pytest collects them in the
    extended tier (a fresh interpreter)."""
    files = sorted({key.split("::")[0] for key in list(extended_tier.FURTHER_CASES) + list(extended_tier.SLOW_TESTS)})
    r = run_python("import sys, pytest\nsys.exit(pytest.main(['--collect-only', '-q', '--extended', "
                   "'-p', 'no:cacheprovider'] + %r))" % [os.path.join("tests", f) for f in files], cwd=REPO)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    found = collections.defaultdict(list)
    for line in r.stdout.splitlines():
        m = re.match(r"tests/([^:]+)::([^\[\s]+)(?:\[(.*)\])?$", line.strip())
        if m:
            found["%s::%s" % (m.group(1), m.group(2))].append(m.group(3))
    return found


def test_the_list_names_collected_tests_and_leaves_a_case_of_each():
    found = _collected()
    for key in extended_tier.SLOW_TESTS:
        assert key in found, key
    for key, cases in extended_tier.FURTHER_CASES.items():
        assert key in found, key
        assert set(cases) <= set(found[key]), (key, sorted(set(cases) - set(found[key])))
        assert set(found[key]) - set(cases), "%s: no case left in every test run" % key


def test_extended_reads_node_ids():
    key, cases = next(iter(extended_tier.FURTHER_CASES.items()))
    path = "tests/" + key
    assert extended_tier.extended("%s[%s]" % (path, cases[0]))
    assert not extended_tier.extended("%s[%s]" % (path, "a case not listed"))
    assert extended_tier.extended("tests/" + next(iter(extended_tier.SLOW_TESTS)))
    assert not extended_tier.extended("tests/test_tiers.py::test_extended_reads_node_ids")
