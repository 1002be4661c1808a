"""The XML files in configs/: up to date, loadable, and rendering their stated exact value."""
import glob
import os
import re

import mitsuba as mi
import numpy as np
import pytest

from mi_plugins.verify import analytic
from mi_plugins.verify.analytic import export, harness
from mi_plugins.verify.analytic.matrix import INTEGRATORS, SPHERE_NEE_BIAS

from conftest import REPO

CONFIGS = os.path.join(REPO, "configs")
NAMES = sorted(analytic.cases())


def test_every_case_has_an_xml_file():
    files = {os.path.splitext(os.path.basename(p))[0] for p in glob.glob(os.path.join(CONFIGS, "*.xml"))}
    assert set(NAMES) <= files, "run `python3 configs/generate.py`"


@pytest.mark.parametrize("name", NAMES)
def test_xml_is_up_to_date(name, tmp_path):
    case = analytic.cases()[name]()
    case.name = name
    fresh = export.export_case(case, str(tmp_path / (name + ".xml")))
    shipped = os.path.join(CONFIGS, name + ".xml")
    fresh_text, shipped_text = (_without_texture_names(open(p).read()) for p in (fresh, shipped))
    # structure exactly; numbers to float32-reduction accuracy (the exact values in the
    # headers come from parallel sums whose last printed digit may differ between machines)
    assert NUMBER.sub("#", fresh_text) == NUMBER.sub("#", shipped_text), "run `python3 configs/generate.py`"
    fresh_numbers, shipped_numbers = (np.array([float(v) for v in NUMBER.findall(t)]) for t in (fresh_text, shipped_text))
    assert np.allclose(fresh_numbers, shipped_numbers, rtol=1e-5, atol=1e-6), "run `python3 configs/generate.py`"


NUMBER = re.compile(r"(?<![\w.])-?\d+\.?\d*(?:[eE][-+]?\d+)?")


def _without_texture_names(text):
    return re.sub(r"textures/\S+?\.exr", "TEX", text)


#: the glossy box has albedos close to one (long, noisy paths): more samples for the power rule
SPP = {"constant_brdf_roughconductor_box": 128}


@pytest.mark.parametrize("name", NAMES)
def test_xml_loads_and_renders_its_exact_value(name):
    """Each file renders (with its default integrator, `path`) the exact value it states.
    Mitsuba's sphere finding (docs/findings.md) is the explicit, bounded bias where it
    applies."""
    path = os.path.join(CONFIGS, name + ".xml")
    text = open(path).read()
    assert "EXACT RADIANCE" in text
    case = analytic.cases()[name]()
    spp = SPP.get(name, 16)
    scene = mi.load_file(path, spp=spp)
    images = harness.render_runs(scene, spp=spp, runs=16, seed=0)
    known = name in INTEGRATORS["path"].known_failures
    out = harness.compare(images, case.expected(), bias=SPHERE_NEE_BIAS * case.expected_mean() if known else 0.0)
    assert out["passed"], out["failures"]
    m = re.search(r"L = ([0-9.eE+-]+), ([0-9.eE+-]+), ([0-9.eE+-]+) \(RGB\) at every pixel", text)
    if m:
        stated = np.array([float(v) for v in m.groups()])
        assert np.allclose(stated, analytic.cases()[name]().expected()[0, 0])
