"""The display's residual check (``residual``, mi_plugins.solution.display.with_residual):
a share of the camera samples at the points the display reads also gather, and their
difference from the reading, over the share, makes the display's expected value the
gather's at every pixel."""
import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.verify.conformance import runner
from test_darkness import panel_on_floor

pytestmark = pytest.mark.skipif(not mi.variant(), reason="needs a Mitsuba variant")

#: the panel 5 cm above the floor at 64 px: rows 44-47 (central columns) are the shadowed
#: floor just in front of the strip that the light passing under the panel lights, where
#: the smooth display without the check reads +547 % / +588 % (tests/test_steep.py)
STRIP = np.s_[44:48, 24:40]


def _band(integrator, spp, runs, seed):
    scene = panel_on_floor(lift=0.05, resolution=64)
    images = runner.render_runs(scene, integrator, spp, [budget.seed(seed) * 1000 + r for r in range(runs)])[0]
    means = images[(slice(None),) + STRIP][..., :3].mean(axis=(1, 2, 3))
    return means.mean(), means.std(ddof=1) / np.sqrt(runs)


@pytest.mark.parametrize("integrator", [
    pytest.param({"type": "qmc_lighttrace", "samples": 100000}, id="qmc_lighttrace"),
    pytest.param({"type": "ray_bundle", "iterations": 24}, id="ray_bundle")])
def test_the_residual_check_removes_the_smooth_display_bias_beside_the_strip(integrator):
    """With ``residual=0.25`` the smooth display matches ``path`` on the shadowed floor beside
    the lit strip; test of the test: without it the field's bias there is over twice
    ``path``'s value and more than 4 standard errors off."""
    ref, ref_se = _band({"type": "path"}, 2048, 8, 50)
    settings = dict(integrator, display="smooth")
    mean, se = _band(dict(settings, residual=0.25), 16, 8, 55)
    budget.close(mean, ref, np.hypot(se, ref_se), what="smooth display with the residual check / path")
    bad, bad_se = _band(settings, 16, 8, 55)
    assert bad > 2.0 * ref and bad - ref > 4 * np.hypot(bad_se, ref_se), (bad, ref, bad_se, ref_se)
