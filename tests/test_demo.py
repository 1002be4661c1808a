"""``mi-plugins demo``: every image written, the smooth displays solved once, the checks'
lines; the split of a solution's seconds between its solve and its display."""
import os

import mitsuba as mi
import numpy as np
import pytest

import mi_plugins
from mi_plugins.app import demo, timesplit

pytestmark = pytest.mark.skipif(not mi.variant(), reason="needs a Mitsuba variant")

#: solve rates for the tests (no measurement: the smallest solves)
RATES = {"ray_bundle": timesplit.SolveRate({"type": "ray_bundle", "display": "smooth"}, 0.0, 1.0),
         "qmc_lighttrace": timesplit.SolveRate({"type": "qmc_lighttrace", "display": "smooth"}, 0.0, 1.0)}


def test_demo_writes_every_image_with_its_errors(tmp_path):
    lines = []
    assert demo.run(str(tmp_path), seconds=0.2, resolution=16, check=False, out=lines.append, frames=0,
                    cache=str(tmp_path / "cache"), rates=RATES) == 0
    names = sorted(os.listdir(tmp_path))
    for name in demo.INTEGRATORS:
        assert name.replace(" ", "_") + ".png" in names, names
    assert "contact_sheet.png" in names and "reference_path.png" in names
    rows = [line for line in lines if "away from the lamp" in line and "RMSE" in line and "Cornell" not in line]
    assert len(rows) == len(demo.INTEGRATORS), lines
    assert sum("1 solve (" in row for row in rows) == 2, rows
    assert not any("nan" in row for row in rows), rows


@pytest.mark.renders_nothing
@pytest.mark.parametrize("settings, message", [
    ((0, 16, 0), "seconds=0: valid: more than 0"),
    ((1, 4, 0), "resolution=4: valid: 8 or more"),
    ((1, 16, 1), "frames=1: valid: 0 (no walkthrough) or 2 or more")])
def test_the_demo_refuses_settings_it_cannot_use(tmp_path, settings, message):
    with pytest.raises(ValueError, match="mi-plugins demo: " + message.replace("(", r"\(").replace(")", r"\)")):
        seconds, resolution, frames = settings
        demo.run(str(tmp_path), seconds=seconds, resolution=resolution, frames=frames, check=False)


class FakeClock:
    """A clock that advances only when the fake solve and render below spend time."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


@pytest.fixture
def fake_machine(monkeypatch):
    """A machine where a solve of size n takes ``cost['solve'] * n`` seconds and a display
    render of s spp ``cost['fixed'] + cost['spp'] * s`` (the first render of a solve
    ``cost['first']`` more); returns (cost, renders: the spp of every render)."""
    clock, cost, renders = FakeClock(), dict(solve=1e-6, fixed=0.02, spp=0.002, first=0.3), []
    monkeypatch.setattr(timesplit.time, "perf_counter", clock)

    def solve(scene, integ, seed=0):
        clock.now += cost["solve"] * integ.samples
        renders.clear()

    def render(scene, integrator=None, spp=0, seed=0, **kw):
        clock.now += cost["fixed"] + cost["spp"] * spp + (cost["first"] if not renders else 0.0)
        renders.append(int(spp))
        return np.zeros((4, 4, 3))
    monkeypatch.setattr(mi_plugins, "solve", solve)
    monkeypatch.setattr(mi, "render", render)
    return cost, renders


def row_faults(info, cost, seconds=10.0, share=0.8):
    """What a solution row of ``seconds`` did wrong on the fake machine (an empty list: nothing)."""
    faults = []
    if info["size"] != int(share * seconds / cost["solve"]) or info["solve_seconds"] != pytest.approx(share * seconds):
        faults.append("the solve did not take its share: %r" % info)
    if info["spp"] not in timesplit.SPP_STEPS or not 0.9 * seconds < info["seconds"] <= seconds:
        faults.append("the row did not fill its seconds: %r" % info)
    else:
        nxt = timesplit.SPP_STEPS[timesplit.SPP_STEPS.index(info["spp"]) + 1]
        if info["seconds"] + cost["spp"] * (nxt - info["spp"]) <= seconds:
            faults.append("a larger camera-sample count would have fitted: %r" % info)
    return faults


@pytest.mark.renders_nothing
def test_a_solution_row_spends_its_share_on_the_solve_and_the_rest_on_camera_samples(fake_machine):
    cost, renders = fake_machine
    rate = timesplit.SolveRate({"type": "qmc_lighttrace", "display": "smooth"}, 0.0, cost["solve"])
    _, info = timesplit.solve_and_display(None, rate, 10.0, share=0.8)
    assert row_faults(info, cost) == [] and renders[-1] == info["spp"] and info["spp"] > 200


@pytest.mark.renders_nothing
@pytest.mark.parametrize("broken", ["no pilot", "half the share"])
def test_the_row_test_fails_a_row_that_wastes_its_seconds(fake_machine, monkeypatch, broken):
    """The test of the test: a display left with 1 spp, a solve given half its share."""
    cost, _ = fake_machine
    rate = timesplit.SolveRate({"type": "qmc_lighttrace", "display": "smooth"}, 0.0, cost["solve"])
    if broken == "no pilot":
        monkeypatch.setattr(timesplit, "spp_for", lambda *a, **k: 1)
    _, info = timesplit.solve_and_display(None, rate, 10.0, share=0.4 if broken == "half the share" else 0.8)
    assert row_faults(info, cost)


@pytest.mark.renders_nothing
def test_an_overrunning_solve_still_leaves_the_display_its_floor_and_corrects_the_rate(fake_machine):
    cost, renders = fake_machine
    rate = timesplit.SolveRate({"type": "qmc_lighttrace", "display": "smooth"}, 0.0, cost["solve"] / 3)
    _, info = timesplit.solve_and_display(None, rate, 10.0, share=0.8)      # the solve takes 3x its share
    assert info["solve_seconds"] == pytest.approx(24.0)
    floor = timesplit.DISPLAY_FLOOR * 0.2 * 10.0
    # (rounded down to a count of SPP_STEPS: at least 4/5 of what fits)
    assert cost["spp"] * info["spp"] + cost["fixed"] >= 0.6 * floor, info         # not 1 spp
    assert info["seconds"] > 24.0 + floor * 0.6                                      # the overrun is reported
    assert rate.per_unit == pytest.approx(cost["solve"]) and rate.size(8.0) == 8000000


@pytest.mark.renders_nothing
def test_the_rate_refuses_an_integrator_without_a_solution():
    with pytest.raises(ValueError, match="integrator 'path' has no view-independent solution"):
        timesplit.SolveRate({"type": "path"}, 0.0, 1.0)


def walk_faults(info, cost, seconds, overhead, frames):
    """What a walk's solution run of ``seconds`` did wrong on the fake machine (empty: nothing)."""
    faults = []
    if info["solve_seconds"] != pytest.approx(timesplit.SOLVE_SHARE["walk"] * (seconds - overhead), rel=1e-3):
        faults.append("the solve did not take its share of the seconds less the overhead: %r" % info)
    if info["overhead"] != pytest.approx(cost["first"] + cost["fixed"] * (frames + 5) + 38 * cost["spp"]):
        faults.append("the overhead is not the display's one-time and per-frame costs and the least pilot: %r" % info)
    nxt = timesplit.SPP_STEPS[timesplit.SPP_STEPS.index(info["spp"]) + 1]
    if info["seconds"] > seconds or info["seconds"] + frames * cost["spp"] * (nxt - info["spp"]) <= seconds:
        faults.append("the frames did not fill the seconds: %r" % info)
    return faults


@pytest.mark.parametrize("fraction, broken", [(1.0, None), (0.25, None), (0.25, "no pilot")])
def test_a_walk_solves_for_its_share_and_fills_the_rest_with_camera_samples(fake_machine, monkeypatch, fraction,
                                                                             broken):
    """One solve for its share of a walk's seconds (at a quarter: of the seconds less the
    overhead a first run measured), the frames' camera samples filling the rest; the test
    of the test: frames left with 1 spp fail."""
    from mi_plugins.app import walkthrough
    cost, _ = fake_machine
    if broken == "no pilot":
        monkeypatch.setattr(timesplit, "spp_for", lambda *a, **k: 1)
    rate = timesplit.SolveRate({"type": "qmc_lighttrace", "display": "smooth"}, 0.0, cost["solve"])
    frames, seconds = 30, 8.0 * fraction
    overhead = 0.0 if fraction == 1.0 else cost["first"] + cost["fixed"] * (frames + 5) + 38 * cost["spp"]
    _, info = walkthrough.render_solution(mi.load_dict(walkthrough.scene_dict(16)), rate,
                                          walkthrough.cornell_walk(frames), seconds, overhead=overhead)
    assert bool(walk_faults(info, cost, seconds, overhead, frames)) == (broken is not None), info
