"""Tests of the `ray_bundle` integrator (stochastic iteration with global ray bundles).

Budgets (tests/budget.py, power rule): the analytic checks run many chains in lockstep
(``rb()``: 8-64 chains, bundles of 16 x 16 lines, 32 x 32 on the 1280-triangle sphere
mesh, burn-in 8 plus 8-24 averaged iterations, 16-32 runs) and reach relative
tolerances of 0.3-1.5 %. The paper's one-chain settings (``PAPER``) are kept where the
test is about them: Hammersley directions (fig. 7) and the 1/sqrt(iterations) law of
one chain.

Burn-in: the image of an iteration misses the bounces beyond it, a bias that decays
like the scene's albedo to the power of the burn-in. Measured (64 chains, 32 runs, mean
relative error at burn-in 4 / 8 / 16): furnace box -0.17 / +0.07 / +0.11 % (+-0.1 %),
Bekaert box and Sierpinski within +-0.08 % at every burn-in, the Phong cases within
+-0.2 %, constant_lightsource_box -5.7 / -1.0 / -0.14 % (+-0.3 %): burn-in 8, 16 for the
Bekaert and Phong cases, 24 for the light-source box. constant_lightsource_sierpinski
(its non-emitting surfaces reflect everything) needs about 72: -19 / -4.4 / -1.7 / -0.4 %
at burn-in 8 / 24 / 40 / 56.
"""
import functools
from unittest import mock

import numpy as np
import pytest

import drjit as dr
import mitsuba as mi
from mi_plugins.verify import analytic
from mi_plugins.patches import gaps
from mi_plugins.base import errors
from mi_plugins.verify.analytic import harness
from mi_plugins.base.errors import Unsupported
from mi_plugins.integrators.ray_bundle.integrator import PAPER_SETTINGS

import budget
from conftest import furnace_rmse, scalar_variant_refusal

RES = 16
#: the paper's algorithm: one chain, bundles of 48 x 48 lines
#: the analytic scenes are modelled as the papers' patches (their patch averages are exact):
#: the tests keep them as modelled (subdivide=false); test_subdivided_patches_stay_exact and the
#: conformance suite render with subdivision
#: the paper's algorithm (the plugin's PAPER_SETTINGS) at the tests' sizes, the scenes' own patches
PAPER = dict(PAPER_SETTINGS, type="ray_bundle", resolution=48, subdivide=False)


def rb(chains=32, averaged=8, burn_in=8, resolution=16, **extra):
    """A ray_bundle dict with ``chains`` chains in lockstep, ``burn_in`` + ``averaged``
    iterations, the scene's triangles as patches."""
    return dict({"type": "ray_bundle", "chains": chains, "iterations": burn_in + averaged, "burn_in": burn_in,
                 "resolution": resolution, "subdivide": False, "first_shot": False, "average_diffuse": False},
                **extra)


def test_subdivided_patches_stay_exact():
    """Long triangles split into sub-triangles (the default: the furnace box's 12 become
    12 x 196, with 64 x 64 lines): the constant radiance stays exact."""
    out = check("furnace_box", rb(32, resolution=64, first_shot=True, average_diffuse=True, subdivide=True), 16, 8)
    assert out.passed, out


def check(name, cfg, runs=16, res=RES, seed=2, **kw):
    case = analytic.cases()[name](resolution=res)
    return analytic.check(case, cfg, spp=1, runs=runs, seed=seed, bias=case.known_bias, **kw)


# Discretisation: ray_bundle keeps one radiance value per triangle. In the furnace and
# constant-radiance cases the exact radiance is constant, so the patch average is exact
# (bias 0). On the diffuse sphere, the point-to-patch form factor of a sphere is the same
# for every receiving point (dA_j / (4 pi R^2)), so replacing the radiance of a patch by
# its average does not change the irradiance anywhere: the only tolerance left is the
# mesh-versus-sphere difference that the case itself documents (case.known_bias).
# (case, integrator, runs, image resolution); the glossy cases (Phong lobes, directional
# emitters) have the heaviest noise: 32-64 chains, 32 runs of an 8 x 8 image (pixels do not
# matter for a constant exact image). On the sphere mesh a chain's 16 x 16 lines reach few
# of its 1280 triangles: 32 x 32 lines lower the per-run SD from 1.2 % to 0.7 % (32 chains;
# 64 chains x 16 x 16 lines would give 0.85 % at the same cost), and with first_shot and 8
# chains the runs are heavy-tailed (excess kurtosis 13).
CASES = [
    ("furnace_box", rb(64), 16, RES),
    ("furnace_sphere_mesh", rb(32, resolution=32), 16, RES),
    ("furnace_sierpinski", rb(64), 16, RES),
    ("bekaert_box", rb(32, burn_in=16), 16, RES),
    ("bekaert_sierpinski", rb(32, burn_in=16), 16, RES),
    ("diffuse_sphere_mesh", rb(32, resolution=32), 24, RES),
    # Mitsuba's analytic sphere, divided into patches along its (u, v) parameterisation:
    # the same form-factor argument holds exactly (the patches are pieces of the sphere)
    ("furnace_sphere", rb(32, resolution=32), 16, RES),
    ("diffuse_sphere", rb(32, resolution=32), 24, RES),
    ("constant_brdf_phong_box", rb(64, burn_in=16), 32, 8),
    ("sierpinski_phong_simulated", rb(32, burn_in=16), 32, 8),
    ("sierpinski_diffuse_exact", rb(64), 16, RES),
    ("sierpinski_diffuse_simulated", rb(64), 16, RES),
    ("constant_lightsource_box", rb(64, averaged=16, burn_in=24), 32, 8),
]


@pytest.mark.parametrize("name,cfg,runs,res", CASES, ids=[c[0] for c in CASES])
def test_analytic_cases(name, cfg, runs, res):
    out = check(name, cfg, runs, res)
    assert out.passed, out


def furnace_cylinder(resolution=RES):
    """The furnace (albedo 0.5, emission 0.5: L = 1) inside a closed analytic cylinder of
    radius 1 from z = -1 to 1 (seen from inside), capped by two analytic disks."""
    from mi_plugins.verify.analytic.case import rgb_dict, truncated_geometric
    from mi_plugins.verify.analytic.classic import ConstantCase
    half = np.full(3, 0.5)

    def furnace(shape):
        return dict(shape, bsdf={"type": "diffuse", "reflectance": rgb_dict(half)},
                    emitter={"type": "area", "radiance": rgb_dict(half)})
    T = mi.ScalarTransform4f
    surfaces = {"tube": furnace({"type": "cylinder", "p0": [0, 0, -1], "p1": [0, 0, 1], "flip_normals": True}),
                "top": furnace({"type": "disk", "to_world": T().translate([0, 0, 1]), "flip_normals": True}),
                "bottom": furnace({"type": "disk", "to_world": T().translate([0, 0, -1])})}
    return ConstantCase("furnace_cylinder", surfaces, ([0.3, 0.2, 0.4], [-0.5, -0.1, -0.9], [0, 1, 0]),
                        lambda d: 0.5 * truncated_geometric(half, d), resolution=resolution)


# Curved patches: a cell of the analytic sphere or cylinder can straddle the terminator of
# a global direction. Its value stands for the part of it that faces the lines, so the
# emission and the BSDF at its uniformly random point are evaluated on the patch's side
# (transfer.on_side); evaluated as they stood, a random point facing away made the whole
# value zero. Measured before (furnace sphere, 32 chains of 16^2 lines, 8 + 8 iterations,
# 64 runs, image mean): -3.0 / -1.6 / -0.84 / -0.38 / -0.20 % at patch size 0.6 / 0.43 (the
# quick matrix's, its row failed at z -8.7) / 0.3 / 0.2 / 0.144, about -0.09 h^2; after,
# within 0.5 SE (0.07-0.08 %) at every size. The capped cylinder at h = 0.8 (8 x 3 cells):
# -2.04 +- 0.06 % before, -0.04 +- 0.06 % after (128 runs). 32 runs: the checks detect 0.8 %,
# the defect is 10-14 SE (seeds 5-7).
CURVED = [("furnace_sphere", lambda: analytic.cases()["furnace_sphere"](resolution=RES), rb(32)),
          ("furnace_cylinder", furnace_cylinder, rb(32, patch_size=0.8))]


@pytest.mark.parametrize("name,case,cfg", CURVED, ids=[c[0] for c in CURVED])
def test_curved_patches_keep_their_power(name, case, cfg):
    """The paper's settings on curved analytic shapes, the sphere at the quick matrix's
    configuration (its patch size 0.43 follows from the 16^2 lines)."""
    out = analytic.check(case(), cfg, spp=1, runs=32, seed=5)
    assert out.passed, out


@pytest.mark.parametrize("name,case,cfg", CURVED, ids=[c[0] for c in CURVED])
def test_curved_patches_evaluated_where_they_face_away_fail(monkeypatch, name, case, cfg):
    """Test of the test: the patch point evaluated as it stands (a point facing away
    from the direction gives the whole cell zero) fails the same checks."""
    from mi_plugins.integrators.ray_bundle import transfer
    monkeypatch.setattr(transfer, "on_side", lambda v, n, sign: v)
    out = analytic.check(case(), cfg, spp=1, runs=32, seed=5)
    assert not out.passed and out.z < -8, out


def test_lightsource_sierpinski(request):
    """constant_lightsource_sierpinski: its non-emitting surfaces reflect everything
    (burn-in about 72, see above) and the chains' radiance is very noisy: per-run SD 4.1 %
    at 64 chains, 64 + 16 iterations (128 runs; not heavy-tailed: skewness 0.24, excess
    kurtosis -0.04); neither first_shot nor average_diffuse nor finer bundles lower it
    (the noise is in the global directions). Measured relative tolerance (32 runs, CPU
    seconds on a loaded machine): 2.6 % (128 chains, 72 + 16 iterations, 20 s), 2.3 %
    (256 chains, 64 + 16, 28 s), 2.5 % (64 chains, 72 + 96, 35 s), 2.1 % (32 chains,
    72 + 128, 42 s); with average_diffuse, first_shot, gather_nee=false 2.1 % (128 chains,
    72 + 16, 39 s). It cannot reach 2 % at a sane cost: it runs only under a documented
    exception of tests/budget.py (EXCEPTIONS)."""
    if budget.limit_for(request.node.nodeid)[1] is None:
        pytest.skip("constant_lightsource_sierpinski cannot reach the power rule's 2 % at a sane cost "
                    "(2.1-2.6 % at 20-42 s CPU); runs once tests/budget.py EXCEPTIONS documents it")
    out = check("constant_lightsource_sierpinski", rb(128, averaged=16, burn_in=72), 48, 8)
    assert out.passed, out


# one-way bundles (bidirectional=false) are 4-5x noisier: a patch receives radiance in half of
# the iterations only (per-run SD 2.3 % against 0.5 % at 64 chains, 8 averaged iterations), and
# only more averaged iterations help (128 chains: 3.2 %, 64 chains x 24 iterations: 1.3 %)
@pytest.mark.parametrize("cfg,runs,res", [(rb(64, estimate="patch"), 16, RES),
                                          (rb(64, averaged=24, bidirectional=False), 32, 8),
                                          (rb(64, direction_sequence="pi"), 16, RES),
                                          (rb(64, stratify_chains=False, estimate="patch"), 16, RES),
                                          (rb(64, averaged=40, stratify_chains=False, bidirectional=False), 32, 8),
                                          (rb(32, first_shot=True, estimate="patch"), 16, RES)],
                         ids=["patch", "one_way", "pi", "independent-patch", "independent-one_way", "first_shot-patch"])
def test_variants_pass_the_furnace(cfg, runs, res):
    out = check("furnace_box", cfg, runs, res, seed=4)
    assert out.passed, out


def test_hammersley_directions_are_wrong_independent_are_right():
    """Paper figure 7, the paper's settings (one chain, 48 x 48 lines, here 128
    iterations): the 1-uniform Hammersley sequence of global directions gives a clearly
    wrong mean (measured +5 %, z about 30); independent random directions pass the same
    check (one chain: per-run SD 1.8 % at 64 iterations, so 128 iterations x 32 runs
    for a tolerance of about 1.2 %)."""
    paper = dict(PAPER, iterations=128)
    good = check("bekaert_box", dict(paper, direction_sequence="independent"), 32, 8, seed=5)
    bad = check("bekaert_box", dict(paper, direction_sequence="hammersley"), 16, 8, seed=5)
    assert good.passed, good
    assert not bad.passed and abs(bad.z) > 8, bad


# ------------------------------------------------------------------ ratio statistics: chains
# (the ratio statistics are about one feature each, and their distributions were measured
# with independent chains: they keep share_diffuse=false; the shared default is tested by
# test_chains_share_their_diffuse_patches and the analytic cases)
#: seeds per RMSE of the chain statistics (one render each). The furnace Sierpinski scene
#: (76 triangles): its per-image error has more independent parts than the box's 12
#: triangles, so the RMSE over a few seeds is steadier (log-SD of the ratio 0.12 against
#: 0.21 for the box at 8 seeds, same cost)
LAW_SEEDS = 24


@functools.lru_cache(maxsize=None)
def _chain_rmses(block):
    """RMSE (furnace Sierpinski, 8 x 8 pixels, LAW_SEEDS renders each, own seeds) of one
    chain with 16 averaged iterations, of one chain with 64, and of 4 independent
    chains (stratify_chains=false) with 16: the paper's settings otherwise."""
    seeds = lambda k: [budget.block_seed(block, 1000 * k + j) for j in range(LAW_SEEDS)]
    rmse = lambda cfg, k: furnace_rmse(dict(PAPER, burn_in=8, **cfg), seeds(k), 8, "sierpinski")
    one = rmse({"iterations": 24}, 0)
    long = rmse({"iterations": 72}, 1)
    four = rmse({"iterations": 24, "chains": 4, "stratify_chains": False, "share_diffuse": False}, 2)
    return one, long, four


@budget.ratio_statistic("ray_bundle.rmse_ratio_iterations")
def rmse_ratio_iterations(block):
    """One chain: RMSE with 16 averaged iterations over the RMSE with 64 (1/sqrt: 2)."""
    one, long, four = _chain_rmses(block)
    return one / long


@budget.ratio_statistic("ray_bundle.rmse_ratio_chains")
def rmse_ratio_chains(block):
    """RMSE of one chain over that of 4 independent chains, same iterations (2)."""
    one, long, four = _chain_rmses(block)
    return one / four


@budget.ratio_statistic("ray_bundle.rmse_ratio_long_chain")
def rmse_ratio_long_chain(block):
    """RMSE of one chain with 4x the iterations over that of 4 chains (1, or more
    where the one chain's iterations are autocorrelated)."""
    one, long, four = _chain_rmses(block)
    return long / four


def test_error_shrinks_like_inverse_sqrt_of_iterations():
    """One chain (the paper's algorithm): 4x the averaged iterations halve the RMSE.
    A ratio of 1 (iterations not averaged) or 4 (1/iterations) is outside the bounds."""
    # measured over 24 seed blocks: 1.73 .. 2.30 (median 1.94, log-SD 0.071)
    budget.ratio("ray_bundle.rmse_ratio_iterations", rmse_ratio_iterations(0), 1.25, 3.2)


def test_chains_are_independent_and_averaged():
    """4 independent chains in lockstep (stratify_chains=false): the error halves against
    one chain of the same iterations, and equals that of one chain with 4x the
    iterations (chains have no autocorrelation between them, so never worse). Chains
    sharing their directions give 1.25 for the first ratio: excluded by its lower
    bound. The mean stays exact with independent chains (the stratified default is
    checked by test_analytic_cases)."""
    # measured over 24 seed blocks: one / four 1.82 .. 2.48 (median 2.02, log-SD 0.076);
    # long / four 0.94 .. 1.20 (median 1.01, log-SD 0.062)
    budget.ratio("ray_bundle.rmse_ratio_chains", rmse_ratio_chains(0), 1.3, 3.4)
    budget.ratio("ray_bundle.rmse_ratio_long_chain", rmse_ratio_long_chain(0), 0.6, 1.7)
    res = check("bekaert_sierpinski", rb(32, burn_in=16, stratify_chains=False, share_diffuse=False), seed=7)
    assert res.passed, res


def test_chains_share_their_diffuse_patches():
    """share_diffuse (the default): every iteration a purely diffuse patch side reflects
    the mean of what all chains' bundles brought it. Small patches (furnace box, patch
    size 0.08: 7 500 patch sides, 16 chains of 12 x 12 lines) meet well under one line
    per chain and iteration; chains that share pass the furnace with the power rule
    (measured: tolerance 1.5 %, RMSE 0.070). The test of the test: the same chains on
    their own give a skewed, heavy-tailed estimate (most of a chain's patch values zero,
    a few large; the light of k bounces is a product of k of them): the same check fails
    or lacks the power (measured: it detects 24 %, RMSE 1.14, at the suite's seeds; in a
    closed diffuse room the renders read 2-6 % low)."""
    cfg = rb(16, averaged=16, resolution=12, subdivide=True, patch_size=0.08)
    out = check("furnace_box", cfg, 16, 8)
    assert out.passed, out
    with mock.patch.object(harness, "OBSERVERS", []):      # (not a check of the suite: its power is the point)
        alone = check("furnace_box", dict(cfg, share_diffuse=False), 16, 8)
    # (it fails, or passes without the power the suite's rule asks for; a heavy tail, so
    # its draws vary: at seed offsets 0 and 2 it detected 24 % and 6.1 % (z -6.7); 0-3 pass)
    lacks_power = alone.relative_tolerance > 2 * budget.POWER_LIMIT
    assert (not alone.passed or lacks_power) and alone.rmse > 2 * out.rmse, (alone, out)


# stratify_chains: one evenly spread direction set per iteration, dealt to the chains
def _direction_sets(shuffle=True, chains=8, count=4000, antipodal=True):
    from mi_plugins.integrators.ray_bundle.directions import stratified_direction_sets
    return stratified_direction_sets(count, chains, budget.rng(3), antipodal, shuffle)


@pytest.mark.parametrize("antipodal", [True, False])
def test_stratified_direction_sets_are_uniform_and_independent_per_chain(antipodal):
    """Every chain's directions are uniform (mean 0, E[z^2] = 1/3) and consecutive ones
    independent (E[w_m . w_m+1] = 0, E[(w_m . w_m+1)^2] = 1/3): 4 chains x 4000
    iterations, each moment within z = 5 standard errors of its exact value (60 values
    per case: z 5 keeps their false-failure share at 3e-5)."""
    w = _direction_sets(antipodal=antipodal, chains=4)
    n = w.shape[0]
    se_mean, se_square = np.sqrt(1 / 3 / n), np.sqrt(4 / 45 / n)   # Var(w_x) = 1/3, Var(w_x^2) = 4/45
    budget.close(w.mean(axis=0), 0.0, se_mean, z=5.0, what="mean direction")
    budget.close((w ** 2).mean(axis=0), 1 / 3, se_square, z=5.0, what="E[w_x^2]")
    t = np.sum(w[1:] * w[:-1], axis=-1)
    budget.close(t.mean(axis=0), 0.0, se_mean, z=5.0, what="E[w_m . w_m+1]")
    budget.close((t ** 2).mean(axis=0), 1 / 3, se_square, z=5.0, what="E[(w_m . w_m+1)^2]")


def test_stratified_direction_sets_cover_the_sphere_and_are_reshuffled():
    """One iteration's set is stratified: the chain average of |a . w| for a random
    axis a has a much smaller spread than for independent directions. The fresh order
    of every iteration decouples the chains: the chain-averaged w_m . w_m+1 spreads like
    an average of independent pairs (variance about 1/(3 chains)); the test of the test:
    without the shuffle every chain turns by the same relative rotation Q and the
    average spreads like tr(Q)/3 (variance 1/9). Measured: 0.049 and 0.112 (4000
    iterations: each variance has a relative SD of about 3 %, the bounds are 2x away)."""
    chains = 8
    w = _direction_sets(chains=chains)
    axes = budget.rng(4).normal(size=(w.shape[0], 1, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    spread = np.std(np.abs(np.sum(axes * w, axis=-1)).mean(axis=1))
    independent_spread = np.sqrt(1 / 12 / chains)                 # Var|a . w| = 1/12
    assert spread < 0.5 * independent_spread, (spread, independent_spread)   # measured 0.30
    pair_var = lambda v: np.var(np.sum(v[1:] * v[:-1], axis=-1).mean(axis=1))
    shuffled, fixed = pair_var(w), pair_var(_direction_sets(shuffle=False, chains=chains))
    assert shuffled < 2 / (3 * chains), shuffled
    assert fixed > 1 / 18, fixed


@functools.lru_cache(maxsize=None)
def _direction_set_rmse(block, chains, n_seeds, variant):
    """RMSE (furnace box, 8 x 8 pixels, seeds 0 .. ``n_seeds`` - 1 of ``block``: the same
    for every variant) of ``chains`` chains with 'independent' directions, 'stratified'
    sets, or stratified sets dealt in a 'fixed_order' (the shuffle patched out with
    unittest.mock)."""
    from mi_plugins.integrators.ray_bundle import directions
    seeds = [budget.block_seed(block, j) for j in range(n_seeds)]
    if variant == "independent":
        return furnace_rmse(rb(chains, stratify_chains=False, share_diffuse=False), seeds, 8)
    if variant == "stratified":
        return furnace_rmse(rb(chains, share_diffuse=False), seeds, 8)
    with mock.patch.object(directions, "stratified_direction_sets",
                           functools.partial(directions.stratified_direction_sets, shuffle=False)):
        return furnace_rmse(rb(chains, share_diffuse=False), seeds, 8)


@budget.ratio_statistic("ray_bundle.rmse_ratio_stratified")
def rmse_ratio_stratified(block):
    """Furnace box, 16 chains, 64 seeds: RMSE of independent over stratified chains."""
    return _direction_set_rmse(block, 16, 64, "independent") / _direction_set_rmse(block, 16, 64, "stratified")


@budget.ratio_statistic("ray_bundle.rmse_ratio_fixed_order")
def rmse_ratio_fixed_order(block):
    """Furnace box, 256 chains, 16 seeds: RMSE of stratified sets dealt in a fixed order
    over that of the shuffled ones (the more chains, the more a common rotation costs)."""
    return _direction_set_rmse(block, 256, 16, "fixed_order") / _direction_set_rmse(block, 256, 16, "stratified")


def test_stratified_chains_lower_the_error():
    """Furnace box: stratified chains lower the RMSE against independent chains; the test
    of the test: stratified sets dealt in a fixed order (every chain turned by the same
    random rotation between iterations) correlate the chains and lose the gain (worse
    than independent chains)."""
    # measured over 24 seed blocks: independent / stratified 1.38 .. 1.70 (median 1.55, log-SD
    # 0.061); fixed order / stratified 3.14 .. 6.31 (median 4.36, log-SD 0.167)
    budget.ratio("ray_bundle.rmse_ratio_stratified", rmse_ratio_stratified(0), 1.12, None)
    budget.ratio("ray_bundle.rmse_ratio_fixed_order", rmse_ratio_fixed_order(0), 1.8, None)


# first_shot: direct light by next-event estimation, bundles carry reflected radiance only
FIRST_SHOT_CASES = [
    ("furnace_box", rb(32), 16, RES),
    ("furnace_sphere_mesh", rb(16, resolution=32), 16, RES),
    # the direct light varies within the triangles while the radiance (1) is constant: a line's
    # point value of it beside its patch's mean reflected part reads -0.4 % (z -6 to -8 with the
    # chains' shared diffuse patches, -3 without; unchanged at burn-in 40): patch values are exact
    ("bekaert_sierpinski", rb(16, burn_in=16, point_sources=False), 16, RES),
    ("diffuse_sphere_mesh", rb(16, resolution=32), 16, RES),
    ("constant_brdf_phong_box", rb(32, burn_in=16), 16, 8),
    ("sierpinski_diffuse_simulated", rb(16), 16, RES),
    # the directional emitters' direct light varies along the box's two-triangle walls while the
    # radiance (L~) is constant: the patch values are exact, a point's direct light plus its
    # patch's reflected part is not (-2 %, z -12 with point sources)
    ("constant_lightsource_box", rb(64, averaged=16, burn_in=24, point_sources=False), 32, 8),
]


@pytest.mark.parametrize("name,cfg,runs,res", FIRST_SHOT_CASES, ids=[c[0] for c in FIRST_SHOT_CASES])
def test_first_shot_analytic_cases(name, cfg, runs, res):
    out = check(name, dict(cfg, first_shot=True), runs, res)
    assert out.passed, out


@budget.ratio_statistic("ray_bundle.rmse_ratio_first_shot")
def rmse_ratio_first_shot(block):
    """Same iterations, furnace sphere mesh (4 chains, 4 seeds): RMSE without over with
    the first shot (its shared running mean: point_sources=false; a light sample per line
    hit is as noisy as the bundles' own estimate, ratio 0.99)."""
    cfg = rb(4, averaged=32, point_sources=False, share_diffuse=False)
    seeds = [budget.block_seed(block, j) for j in range(4)]
    plain = furnace_rmse(cfg, seeds, RES, "sphere_mesh")
    shot = furnace_rmse(dict(cfg, first_shot=True), seeds, RES, "sphere_mesh")
    return plain / shot


def test_first_shot_halves_the_error():
    """Same iterations, furnace sphere mesh: the light sample (with MIS) replaces the
    random-direction estimate of the direct light; measured RMSE ratio 2.0 (furnace
    sphere mesh), 1.7 (diffuse sphere), 1.8 (Sierpinski)."""
    # measured over 24 seed blocks: 1.93 .. 2.01 (median 2.00, log-SD 0.008: same seeds)
    budget.ratio("ray_bundle.rmse_ratio_first_shot", rmse_ratio_first_shot(0), 1.8, None)


def test_first_shot_that_counts_emission_twice_fails(monkeypatch):
    """Test of the test: a first shot that keeps the emission in the transported
    radiance (Le counted by the bundles and by the light sample) must fail the check."""
    from mi_plugins.integrators.ray_bundle.transfer import Transport
    source, point_source = Transport.source, Transport.point_source

    def doubled(self, si, tri):
        return source(self, si, tri) + mi.Color3f(si.emitter(self.scene).eval(si))

    def doubled_point(self, si, active, rng):
        return point_source(self, si, active, rng) + mi.Color3f(si.emitter(self.scene, active).eval(si, active))
    monkeypatch.setattr(Transport, "source", doubled)
    monkeypatch.setattr(Transport, "point_source", doubled_point)
    res = check("furnace_box", rb(32, first_shot=True))
    assert not res.passed and abs(res.z) > 8, res


def test_diffuse_patches_share_one_direct_light_estimate(monkeypatch):
    """first_shot on purely diffuse patches: one light sample per patch side and
    iteration (the initial state and every reflection), shared by all 32 chains through
    its running mean, not one per chain and patch. Exact in the furnace box; test of the
    test: a shared mean 10 % low fails (the direct light is about a third of the
    image: 3 % gave z = -4.9, within the bound)."""
    from mi_plugins.integrators.ray_bundle import direct, frozen
    monkeypatch.setattr(frozen, "ENABLED", False)       # count the calls of every iteration, not a recording
    calls, update = [], direct.SharedDirect.update

    def counted(self):
        calls.append((dr.width(self.state.sum), self.table.count))
        update(self)
    monkeypatch.setattr(direct.SharedDirect, "update", counted)
    cfg = rb(32, first_shot=True, point_sources=False, adaptive=False)
    assert check("furnace_box", cfg).passed
    assert calls and all(width == count for width, count in calls)
    per_render = cfg["iterations"] + 1
    assert len(calls) % per_render == 0, (len(calls), per_render)
    mean = direct.SharedDirect.mean
    monkeypatch.setattr(direct.SharedDirect, "mean", lambda self, tri, active=True: mean(self, tri, active) * 0.9)
    low = check("furnace_box", cfg)
    assert not low.passed and low.z < -8, low


def test_default_chains_fit_a_quarter_of_the_memory():
    """chains=64 by default, fewer (at least 1) where 64 would need over a quarter of
    the available memory (lanes and lines of a chain); an explicit value is kept (and
    refused when it does not fit)."""
    from mi_plugins.integrators.ray_bundle.memory import chain_bytes, default_chains
    per_chain = chain_bytes(2000, 32)        # 1000 patches, two sides, 32^2 lines
    assert default_chains(64, 2000, 32, None) == 64
    assert default_chains(64, 2000, 32, 4 * per_chain * 100) == 64
    assert default_chains(64, 2000, 32, 4 * per_chain * 10 + 1) == 10
    assert default_chains(64, 2000, 32, 1) == 1
    integ = mi.load_dict({"type": "ray_bundle"})
    assert integ.chains is None and (integ.resolution, integ.iterations, integ.burn_in) == (32, 16, 8)
    assert integ.first_shot and integ.average_diffuse and integ.max_depth == -1 and integ.adaptive


# hide_emitters as Mitsuba means it: camera rays pass through area emitters
def test_hide_emitters_passes_camera_rays_through_emitters():
    """Furnace box: every wall emits, so with hide_emitters the camera sees nothing
    (black, as Mitsuba's path renders it); without it the same renders show L = 1.
    (What lies behind a hidden lamp is checked against path by the coverage row
    case:hide_emitters.)"""
    case = analytic.furnace(0.5, 0.5, "box", resolution=8)
    hidden = harness.render_runs(case.scene(rb(16, averaged=8, hide_emitters=True)), 1, 16, 2)
    assert np.all(np.asarray(hidden) == 0)
    path = np.array(mi.render(case.scene({"type": "path", "hide_emitters": True}), spp=16))
    assert np.all(path == 0)
    shown = harness.render_runs(case.scene(rb(16, averaged=8)), 1, 16, 2)
    assert np.asarray(shown).mean() > 0.9


# wrong images must fail: the structure test of the harness for a finite-element method
@pytest.mark.parametrize("estimate", ["gather", "patch"])
def test_wrong_images_fail(estimate):
    """Diffuse sphere mesh: the renders pass against the exact image and fail, by the
    structure test, against the mirrored exact image (right mean, wrong place) and
    against one with 1.25x its contrast."""
    case = analytic.cases()["diffuse_sphere_mesh"](resolution=RES)
    # the most powerful configuration: first shot and averaged diffuse patches (the patch
    # estimate needs 16 chains for a tolerance of 0.7 %; 8 chains: 1.3-1.4 %, 16 x 16 lines: 2.5 %)
    cfg = rb(8 if estimate == "gather" else 16, resolution=32, first_shot=True, average_diffuse=True,
             estimate=estimate)
    images = harness.render_runs(case.scene(cfg), 1, 16, 8)
    exact = case.expected()
    right = harness.compare(images, exact, bias=case.known_bias)
    assert right["passed"], right["failures"]
    # the part of the slope tolerance that the known mesh bias takes
    bias_slope = right["slope_tolerance"] - right["z_limit"] * right["slope_se"]
    mean = exact.mean()
    for wrong, slope in ((exact[:, ::-1], None), (mean + 1.25 * (exact - mean), 0.8)):
        out = harness.compare(images, wrong, bias=case.known_bias)
        assert not out["passed"] and any("image structure" in f for f in out["failures"]), out["failures"]
        assert abs(out["slope"] - 1) > 8 * out["slope_se"], {k: out[k] for k in ("slope", "slope_se", "failures")}
        if slope is not None:       # regressed on 1.25x the structure, the right image has slope 1/1.25
            budget.close(out["slope"], slope, out["slope_se"], slack=0.8 * bias_slope, what="slope on 1.25x contrast")


# average_diffuse: final gathering from the diffuse patches' averages over chains and iterations
# (gather_nee=true is exact where the direct light is uniform over each patch: the furnace,
# the spheres, uniform emission; see test_gather_nee_splits_a_patch_constant_radiance)
AVERAGE_CASES = [("furnace_box", {}), ("furnace_sphere_mesh", {"first_shot": True}),
                 ("bekaert_sierpinski", {}), ("bekaert_sierpinski", {"first_shot": True, "gather_nee": False}),
                 ("diffuse_sphere_mesh", {"first_shot": True}),
                 ("sierpinski_diffuse_simulated", {"first_shot": True}),
                 # nothing diffuse: every patch keeps the per-chain estimate
                 ("constant_brdf_phong_box", {"first_shot": True}),
                 # mixed: diffuse walls averaged, emitting (glossy) walls per chain
                 ("constant_lightsource_box", {}),
                 # the direct light averaged with the rest (gather_nee=false)
                 ("furnace_sphere_mesh", {"first_shot": True, "gather_nee": False}),
                 ("constant_lightsource_box", {"first_shot": True, "gather_nee": False})]
#: chains, averaged iterations, burn-in, runs, image resolution per case
AVERAGE_BUDGET = {"furnace_box": (16, 8, 8, 16, RES), "furnace_sphere_mesh": (8, 8, 8, 16, RES),
                  "bekaert_sierpinski": (16, 8, 16, 16, RES), "diffuse_sphere_mesh": (8, 8, 8, 16, RES),
                  "sierpinski_diffuse_simulated": (8, 8, 8, 16, RES),
                  "constant_brdf_phong_box": (32, 8, 16, 32, 8), "constant_lightsource_box": (32, 16, 24, 32, 8)}


@pytest.mark.parametrize("name,extra", AVERAGE_CASES, ids=[
    "%s%s%s" % (n, "-fs" if e.get("first_shot") else "", "-no_nee" if "gather_nee" in e else "") for n, e in AVERAGE_CASES])
def test_average_diffuse_analytic_cases(name, extra):
    chains, averaged, burn_in, runs, res = AVERAGE_BUDGET[name]
    out = check(name, rb(chains, averaged, burn_in, average_diffuse=True, **extra), runs, res, seed=3)
    assert out.passed, out


@pytest.mark.parametrize("name,cfg,runs,res", [
    ("furnace_sphere_mesh", rb(32, averaged=16, average_diffuse=True, estimate="patch"), 32, 8),
    # one way (see test_variants_pass_the_furnace); on the sphere mesh 32 chains x 24 averaged
    # iterations still leave a per-run SD of 2.4 % (skewed): the box, 64 chains
    ("furnace_box", rb(64, averaged=24, average_diffuse=True, bidirectional=False), 32, 8),
    ("furnace_box", rb(32, averaged=24, average_diffuse=True, estimate="patch", first_shot=True,
                       bidirectional=False), 32, 8)], ids=["patch", "one_way", "patch-fs-one_way"])
def test_average_diffuse_variants_pass_the_furnace(name, cfg, runs, res):
    out = check(name, cfg, runs, res, seed=4)
    assert out.passed, out


@budget.ratio_statistic("ray_bundle.rmse_ratio_average_diffuse")
def rmse_ratio_average_diffuse(block):
    """Same iterations, furnace sphere mesh, first shot, 16 chains, 4 seeds: RMSE without
    over with average_diffuse."""
    cfg = rb(16, averaged=16, first_shot=True, share_diffuse=False)
    seeds = [budget.block_seed(block, j) for j in range(4)]
    plain = furnace_rmse(cfg, seeds, 8, "sphere_mesh")
    averaged = furnace_rmse(dict(cfg, average_diffuse=True), seeds, 8, "sphere_mesh")
    return plain / averaged


def test_average_diffuse_lowers_the_error():
    """The average over chains and iterations replaces one chain's stored value."""
    # measured over 24 seed blocks: 5.98 .. 13.2 (median 8.96, log-SD 0.20); the draw of seed
    # offset 1 read 2.67 (the chains without averaging are heavy-tailed: a lower tail the 24
    # blocks did not show), so the bound is 1.5, still far from 1 (no gain)
    budget.ratio("ray_bundle.rmse_ratio_average_diffuse", rmse_ratio_average_diffuse(0), 1.5, None)


@pytest.mark.parametrize("first_shot,gather_nee,averaged", [(False, True, "L"), (True, True, "L"), (True, False, "R")],
                         ids=["emission-twice", "direct-twice", "direct-missing"])
def test_average_of_the_wrong_radiance_fails(monkeypatch, first_shot, gather_nee, averaged):
    """Test of the test: the average must hold exactly what the gathered point does not
    add itself. Averaging the whole stored radiance L while the gathered point adds its
    emission (or, with first shot, its direct light) again, or averaging only the
    reflected part R when the direct light is not added at the gathered point
    (``gather_nee=false``), must fail the furnace check."""
    from mi_plugins.integrators.ray_bundle import RayBundleIntegrator
    monkeypatch.setattr(RayBundleIntegrator, "_averaged_radiance",
                        lambda self, state: [state.L[0] if averaged == "L" else state.R])
    cfg = rb(16, average_diffuse=True, first_shot=first_shot, gather_nee=gather_nee)
    res = check("furnace_box", cfg, seed=4)
    assert not res.passed and abs(res.z) > 8, res


def test_gather_nee_splits_a_patch_constant_radiance():
    """Finding: in the Bekaert box (two albedos, emission 1 - a, on alternate faces of two
    triangles each) the reflected radiance L - Le is constant on every face, but its
    parts are not: the direct light T Le varies across a face (the neighbouring faces
    emit differently) and the rest, T (L - Le) - T Le, the other way. gather_nee=true
    takes the first part at the gathered point and the second from its patch average,
    so the discretisation is no longer exact: the image mean is 0.6 % low (measured
    0.99397 +- 0.00010 at these 8 x 8 pixels, 224 runs; 0.9936 at 16 x 16 pixels; z about
    -6.6 with 16 runs, the chains sharing each diffuse patch's direct light); gather_nee=false
    averages the constant sum and passes."""
    case = analytic.cases()["bekaert_box"](resolution=8)
    cfg = rb(32, averaged=16, burn_in=16, first_shot=True, average_diffuse=True, point_sources=False)
    split = analytic.check(case, cfg, spp=1, runs=32, seed=1)
    whole = analytic.check(case, dict(cfg, gather_nee=False), spp=1, runs=16, seed=1)
    assert not split.passed and split.z < -5, split
    budget.close(split.mean, 0.9940, split.se, slack=0.001, what="gather_nee=true image mean (Bekaert box)")
    assert whole.passed, whole


def test_average_diffuse_progress_counts_the_final_gathering():
    """iteration_count = iterations + final-gathering passes; stopping during the
    iterations still runs the passes of the finished averaged iterations; a callback
    that keeps asking to stop cuts them to one. The image is exact in the furnace
    either way (to the noise of a few iterations)."""
    scene = analytic.furnace(0.5, 0.5, "box", resolution=RES).scene(
        dict(PAPER, iterations=10, burn_in=2, average_diffuse=True, chains=4, adaptive=False))
    integ = scene.integrator()
    assert integ.iteration_count(1) == 10 + 8 and integ.iteration_count(2) == 20 + 18
    seen = []
    integ.progress_callback = lambda done, total: seen.append((done, total))
    mi.render(scene, spp=1, seed=budget.seed(1))
    assert seen == [(k, 18) for k in range(1, 19)]
    asked = []

    def stop_once(done, total):
        asked.append(done)
        return done != 6
    integ.progress_callback = stop_once
    img = np.array(mi.render(scene, spp=1, seed=budget.seed(1)))
    assert integ.progress.done == 6 + 4 and integ.progress.interrupted and asked == list(range(1, 11))
    # a sanity bound (per-run SD of the mean ~2 % here; the values are tested elsewhere):
    # weighting the finished passes as if all had run would give 0.5 or less
    assert np.all(np.isfinite(img)) and abs(img.mean() - 1.0) < 0.2
    integ.progress_callback = lambda done, total: done < 6
    img = np.array(mi.render(scene, spp=1, seed=budget.seed(1)))
    integ.progress_callback = None
    assert integ.progress.done == 6 + 1 and np.all(np.isfinite(img)) and abs(img.mean() - 1.0) < 0.2
    a, b = np.array(mi.render(scene, seed=budget.seed(5), spp=1)), np.array(mi.render(scene, seed=budget.seed(5), spp=1))
    assert_same_image(a, b)


def assert_same_image(a, b):
    """A fixed seed gives the same image, up to the order of float additions: the
    scatter-adds reduce per-core copies (dr.ReduceMode.Expand) in an order that depends
    on the thread schedule (bitwise equal on an idle machine; a difference in the last
    bits was seen once under load)."""
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)


def test_a_shape_without_patches_is_rejected_by_name():
    """Meshes and the analytic rectangle, disk, sphere and cylinder have patches; other
    shapes (here an instance) are refused before any work, naming the plugin and the
    shape, also through mi.render (where Mitsuba chains it)."""
    d = analytic.furnace(0.5, 0.5, "box", resolution=8).scene_dict(dict(PAPER, iterations=2))
    d["group"] = {"type": "shapegroup", "s": {"type": "cube", "to_world": mi.ScalarTransform4f().scale(0.1)}}
    d["inst"] = {"type": "instance", "shapegroup": {"type": "ref", "id": "group"}}
    scene = mi.load_dict(d, optimize=False)
    with pytest.raises(Unsupported, match=r"ray_bundle: the shape 'instance' \(id 'inst'\) is not supported: .*"
                                          r"convert the shape to a triangle mesh"):
        scene.integrator().render(scene, 0, seed=0, spp=1)
    e = _refusal(scene)
    assert e.feature == "instance", str(e)


def test_delta_lights_need_first_shot():
    d = analytic.furnace(0.5, 0.5, "box", resolution=8).scene_dict(dict(PAPER, iterations=2))
    d["lamp"] = {"type": "point", "position": [0, 0, 0]}
    with pytest.raises(ValueError, match=r"ray_bundle: emitter 'lamp' \(PointLight\) is a delta light.*first_shot=true"):
        scene = mi.load_dict(d, optimize=False)
        scene.integrator().render(scene, 0, seed=0, spp=1)


def _furnace_with(bsdf, **cfg):
    d = analytic.furnace(0.5, 0.5, "box", resolution=8).scene_dict(dict(PAPER, iterations=2, burn_in=0, **cfg))
    shape = next(k for k, v in d.items() if isinstance(v, dict) and "bsdf" in v)
    d[shape]["bsdf"] = bsdf
    return mi.load_dict(d), shape


def _refusal(scene):
    """The refusal mi.render raises (Mitsuba chains it: the package's error is a cause)."""
    with pytest.raises(Exception) as err:
        mi.render(scene, spp=1)
    e = err.value
    while e is not None and not isinstance(e, Unsupported):
        e = e.__cause__
    assert e is not None, err.value
    return e


@pytest.mark.parametrize("bsdf,feature,why", [
    ({"type": "conductor"}, "conductor", "purely specular"),
    ({"type": "dielectric"}, "dielectric", "purely specular"),
    ({"type": "null"}, "null", "null lobe"),
    ({"type": "mask", "opacity": 0.5, "bsdf": {"type": "diffuse"}}, "mask", "null lobe"),
    ({"type": "thindielectric"}, "thindielectric", "null lobe"),
    ({"type": "polarizer"}, "polarizer", "null lobe"),
    ({"type": "roughdielectric", "alpha": 0.2}, "roughdielectric", "transmits"),
    ({"type": "twosided", "bsdf": {"type": "conductor"}}, "twosided", "purely specular")])
def test_surfaces_the_bundles_cannot_cross_are_refused(bsdf, feature, why):
    """Before any work, with the integrator, the feature (plugin and shape), why and what
    to use instead. Formerly a delta surface gave a RuntimeWarning only and null lobes,
    transmission nothing (a wrong image)."""
    scene, shape = _furnace_with(bsdf)
    e = _refusal(scene)
    text = str(e)
    assert e.integrator == "ray_bundle" and e.feature == feature, text
    assert text.startswith("ray_bundle: the BSDF '%s' of shape '%s' is not supported" % (feature, shape)), text
    assert why in text and "'path'" in text, text


def test_delta_surfaces_render_with_a_warning_when_accepted():
    """delta_surfaces='camera_only': the user accepts the missing light; a RuntimeWarning
    names the shapes."""
    scene, shape = _furnace_with({"type": "conductor"}, delta_surfaces="camera_only")
    with pytest.warns(RuntimeWarning, match=r"shape\(s\) '%s' have purely delta" % shape):
        img = np.array(mi.render(scene, spp=1))
    assert np.all(np.isfinite(img))


def test_participating_media_are_refused():
    scene, shape = _furnace_with({"type": "diffuse"})
    d = analytic.furnace(0.5, 0.5, "box", resolution=8).scene_dict(dict(PAPER, iterations=2, burn_in=0))
    d["sensor"]["medium"] = {"type": "homogeneous", "sigma_t": 0.1}
    e = _refusal(mi.load_dict(d))
    assert e.feature == "homogeneous" and "volpath" in str(e), str(e)


def test_fixed_seed_is_deterministic_and_progress_stops():
    scene = analytic.furnace(0.5, 0.5, "box", resolution=RES).scene(dict(PAPER, iterations=6, burn_in=1))
    a, b = np.array(mi.render(scene, seed=budget.seed(5), spp=1)), np.array(mi.render(scene, seed=budget.seed(5), spp=1))
    assert_same_image(a, b)
    assert not np.allclose(a, np.array(mi.render(scene, seed=budget.seed(6), spp=1)), rtol=1e-3)
    integ = scene.integrator()
    integ.progress_callback = lambda done, total: done < 3
    img = np.array(mi.render(scene, spp=1, seed=budget.seed(0)))
    integ.progress_callback = None
    assert integ.progress.done == 3 and np.all(np.isfinite(img))


def test_xml():
    scene = mi.load_string("""<scene version="3.0.0"><integrator type="ray_bundle">
        <integer name="iterations" value="5"/><integer name="resolution" value="7"/>
        <string name="direction_sequence" value="halton"/><boolean name="bidirectional" value="false"/>
        <integer name="chains" value="3"/><boolean name="first_shot" value="true"/></integrator></scene>""")
    integ = scene.integrator()
    assert (integ.iterations, integ.resolution, integ.direction_sequence, integ.bidirectional, integ.chains,
            integ.first_shot, integ.stratify_chains) == (5, 7, "halton", False, 3, True, False)
    scene = mi.load_string("""<scene version="3.0.0"><integrator type="ray_bundle">
        <integer name="chains" value="3"/><boolean name="stratify_chains" value="false"/>
        <boolean name="average_diffuse" value="true"/><boolean name="gather_nee" value="false"/>
        <boolean name="hide_emitters" value="true"/></integrator></scene>""")
    integ = scene.integrator()
    assert (integ.stratify_chains, integ.average_diffuse, integ.gather_nee, integ.hide_emitters) == (
        False, True, False, True)
    assert mi.load_dict(dict(PAPER, chains=3)).stratify_chains is True


@pytest.mark.parametrize("params,needle", [
    ({"iterations": 0}, "iterations=0"),
    ({"iterations": -2}, "iterations=-2"),
    ({"resolution": 0}, "resolution=0"),
    ({"resolution": -4}, "resolution=-4"),
    ({"chains": 0}, "chains=0"),
    ({"estimate": "splat"}, "estimate='splat'"),
    ({"direction_sequence": "sobol"}, "direction_sequence='sobol'"),
    ({"direction_sequence": "halton", "stratify_chains": True}, "stratify_chains=true needs direction_sequence"),
    ({"patch_size": 0.0}, "patch_size=0.0 is invalid; valid range: a finite number > 0"),
    ({"patch_size": -1}, "patch_size=-1 is invalid"),
    ({"subdivide": "false"}, "subdivide='false' is invalid; valid range: a boolean"),
])
def test_bad_parameters(params, needle):
    with pytest.raises(Exception) as err:
        mi.load_dict(dict(PAPER, **params))
    assert needle in str(err.value), str(err.value)


def test_wrong_variant():
    """A scalar variant is refused with a message naming it and the supported variants
    (by mi_plugins.register(), or by the integrator's constructor if registered anyway)."""
    refused, out = scalar_variant_refusal("ray_bundle")
    assert refused and "scalar_rgb" in out and "llvm_ad_rgb" in out, out


def _lamp_under_ceiling_error(monkeypatch=None, epsilon=None):
    """mi.cornell_box() with its lamp 1e-4 under the ceiling (the classic Cornell data:
    0.1 mm in 549 mm): the paper's ray_bundle (emission carried by the bundles) against
    path, relative difference of the image means and its SE."""
    from mi_plugins.verify.conformance import scene_library
    from mi_plugins.integrators.ray_bundle import transfer
    if epsilon is not None:
        monkeypatch.setattr(transfer, "LINE_EPSILON", epsilon)
    d = scene_library.mitsuba_cornell(8)
    d["light"]["to_world"] = mi.ScalarTransform4f().translate([0, 1 - 1e-4, 0]).rotate([1, 0, 0], 90).scale(0.235)
    scene = mi.load_dict(d)
    path = [np.array(mi.render(scene, integrator=mi.load_dict({"type": "path"}), spp=2048, seed=budget.seed(60 + k))).mean()
            for k in range(4)]
    cfg = rb(16, averaged=16, burn_in=24, resolution=64, subdivide=True)
    runs = [np.array(mi.render(scene, integrator=mi.load_dict(cfg), spp=1, seed=budget.seed(70 + k))).mean()
            for k in range(16)]
    se = np.hypot(np.std(runs, ddof=1) / 4, np.std(path, ddof=1) / 2) / np.mean(path)
    return np.mean(runs) / np.mean(path) - 1, se


def test_lines_do_not_skip_a_lamp_just_under_the_ceiling():
    """Lines walk through every surface; continuing past a hit with Mitsuba's spawn_ray
    offset (~2e-4 here) skipped the lamp behind the ceiling: -25.5 +- 2.2 % (measured at
    these seeds); now -3.2 +- 2.4 %, within the patch bias (0.5 %) and 4.5 SE."""
    error, se = _lamp_under_ceiling_error()
    budget.close(error, 0.0, se, slack=0.005, z=4.5, what="lamp under the ceiling: relative image mean")


def test_a_coarse_line_offset_would_skip_the_lamp(monkeypatch):
    """The test of the test: an offset of 1e-3 (relative) skips the lamp."""
    error, se = _lamp_under_ceiling_error(monkeypatch, epsilon=1e-3)
    assert error < -0.1 and error + 4.5 * se + 0.005 < 0, (error, se)


def test_a_layout_beyond_the_available_memory_is_refused(monkeypatch):
    """Chains x patch sides (BYTES_PER_LANE measured per lane) plus their bundles' lines
    above the available memory: a clear error naming the chains that fit, before any
    kernel runs (1 M triangles with 64 chains needed 10.8 GB); above a quarter of it, a
    warning."""
    from mi_plugins.integrators.ray_bundle import integrator as module
    from mi_plugins.integrators.ray_bundle import memory
    scene = analytic.furnace(0.5, 0.5, "box", resolution=4).scene(rb(64))     # 12 triangles: 1536 lanes
    per_chain = memory.chain_bytes(24, 16)
    monkeypatch.setattr(module, "available_memory", lambda: 10 * per_chain)
    fit = (10 * per_chain - 12 * memory.BYTES_PER_PATCH) // per_chain
    with pytest.raises(MemoryError, match=r"ray_bundle: chains=64 x 24 patch sides \(12 patches\) x 1 order\(s\) = "
                                          r"0.00154 M lanes and 0.0164 M lines need about [0-9.]+ GB per iteration, "
                                          r"more than the [0-9.]+ GB available; valid range here: chains <= %d" % fit):
        scene.integrator().render(scene, 0, seed=0, spp=1)
    monkeypatch.setattr(module, "available_memory", lambda: 3 * 64 * per_chain)
    with pytest.warns(RuntimeWarning, match="over a quarter of"):
        scene.integrator().render(scene, 0, seed=0, spp=1)
    monkeypatch.setattr(module, "available_memory", lambda: None)        # not known: no check
    mi.render(scene, spp=1, seed=1)


def test_mis_weight_of_an_infinite_light_pdf_is_zero_not_nan():
    """Mitsuba's sphere emitter can return an infinite light pdf with a finite sample
    weight (found as 15 NaN pixels in 16 renders of `ray_bundle+first_shot` inside
    Bekaert's analytic sphere); the power heuristic then gives 0, as Mitsuba's `path`
    does, never inf / inf."""
    from mi_plugins.light.direct import _power_heuristic
    w = np.array(_power_heuristic(mi.Float([float("inf"), 1.0, 0.0, 2.0]), mi.Float([0.3, float("inf"), 1.0, 2.0])))
    assert np.array_equal(w, [0.0, 0.0, 0.0, 0.5])


# ------------------------------------------------------------------ shading normals, point sources, alpha
def test_bsdf_over_cosine_divides_by_the_geometric_cosine():
    """The bundles' power per unit area carries the geometric cosine |n . w| (a line
    bundle's projected area); the BSDF value Mitsuba returns carries the shading cosine.
    Their ratio times the power must be f cos_sh L, what a path tracer integrates: with a
    shading frame tilted 30 degrees from the geometric normal, dividing by the shading
    cosine (the former formula) is off by cos_geo / cos_sh."""
    from mi_plugins.integrators.ray_bundle.transfer import bsdf_over_cosine
    bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.6}})
    si = dr.zeros(mi.SurfaceInteraction3f, 1)
    si.n = mi.Normal3f(0, 0, 1)
    tilt = np.radians(30.0)
    si.sh_frame = mi.Frame3f(mi.Normal3f(float(np.sin(tilt)), 0.0, float(np.cos(tilt))))
    si.wi = si.to_local(mi.Vector3f(0, 0, 1))
    source = dr.normalize(mi.Vector3f(0.7, 0.2, 0.6))          # toward the source (world)
    radiance = 2.0
    power = radiance * float(dr.dot(si.n, source)[0])           # per unit area, geometric cosine
    got = float((bsdf_over_cosine(si, bsdf, source) * power).x[0])
    cos_sh = float(dr.dot(si.sh_frame.n, source)[0])
    budget.close(got, 0.6 / np.pi * cos_sh * radiance, 1e-6, what="f cos_sh L")
    assert abs(cos_sh - float(dr.dot(si.n, source)[0])) > 0.1       # the two cosines differ here


def _stage_cell(key, cfg, runs, seed, resolution=8):
    """Image means (runs renders) of a coverage row's scene with the ray_bundle dict ``cfg``."""
    from mi_plugins.verify.coverage import matrix
    scene = mi.load_dict(matrix.rows()[key].build(resolution))
    integ = mi.load_dict(cfg)
    return np.array([np.array(mi.render(scene, integrator=integ, spp=1, seed=budget.seed(seed + k))).mean()
                     for k in range(runs)])


#: the lamp facing a ceiling 1 cm above it (coverage row case:light_facing_ceiling): path's
#: image mean at 8 x 8 px (16 runs x 4096 spp), relative SE 1.2 % (the light reaches the
#: camera through the 1 cm gap: noisy on both sides)
CEILING_PATH, CEILING_PATH_SE = 0.002045, 0.012
#: the matrix's ray_bundle settings with 64 chains: 16 chains leave a per-run SD of 50 %
#: (heavy-tailed), 64 chains 22 %
CEILING_CFG = {"type": "ray_bundle", "chains": 64, "resolution": 16, "iterations": 12, "burn_in": 6}


def test_lamp_facing_a_ceiling_1cm_above(monkeypatch):
    """The ceiling over the lamp is bright and hidden (the lamp's dark back covers it);
    the ring around it is dim and seen. A line leaving a ceiling patch that straddles the
    lamp's edge carried the patch's average direct light: +93 % on the image mean (the
    brief's +92 %; the matrix's patch size 0.6). The direct light is now evaluated where
    the line leaves (point sources): measured +8 % +- 5.5 % (16 runs); the bound is z 4.5
    on the combined SE plus 5 % of patch bias. (ray_bundle refuses this scene, a lamp
    facing a surface closer than half its patches, ``mi_plugins.patches.gaps``: the light that
    bounces in the gap leaves it as patch averages; the point sources are tested with
    the refusal off.)"""
    monkeypatch.setattr(gaps, "refuse_trapped_lights", lambda *a: None)
    means = _stage_cell("case:light_facing_ceiling", CEILING_CFG, 16, 300)
    se = np.hypot(means.std(ddof=1) / 4, CEILING_PATH_SE * CEILING_PATH)
    budget.close(means.mean(), CEILING_PATH, se, slack=0.05 * CEILING_PATH, what="ceiling image mean")


def test_lamp_facing_a_ceiling_fails_with_patch_averaged_sources(monkeypatch):
    """Test of the test: the lines carrying their patch's value (the source term averaged
    over the patch, as before) give +93 % (measured 0.00395, per-run SD 18 %)."""
    from mi_plugins.integrators.ray_bundle import transfer
    monkeypatch.setattr(gaps, "refuse_trapped_lights", lambda *a: None)
    monkeypatch.setattr(transfer.Transport, "carried",
                        lambda self, state, slot, src, active: [dr.gather(mi.Color3f, state.L[0], slot, active)])
    means = _stage_cell("case:light_facing_ceiling", CEILING_CFG, 8, 300)
    assert means.mean() > 1.5 * CEILING_PATH, means.mean()


def test_alpha_is_the_cameras_coverage():
    """rgba film: the alpha channel is the share of each pixel's camera samples that hit a
    surface, as path makes it (the stage is open above: the top rows see nothing); it was
    1 everywhere."""
    from mi_plugins.verify.coverage import matrix
    d = matrix.rows()["format:rgba"].build(8)
    scene = mi.load_dict(d)
    ours = np.array(mi.render(scene, integrator=mi.load_dict(dict(CEILING_CFG, chains=8)), spp=1, seed=1))
    path = np.array(mi.render(scene, integrator=mi.load_dict({"type": "path"}), spp=256, seed=1))
    assert ours.shape[-1] == 4 and path[..., 3].min() < 0.5
    # per pixel: ours averages 6 passes x 8 chains = 48 samples, path 256 (binomial SD <= 0.08)
    assert np.abs(ours[..., 3] - path[..., 3]).max() < 0.4
    budget.close(ours[..., 3].mean(), path[..., 3].mean(), 0.08 / 8, what="mean alpha")


# ------------------------------------------------------------------ sizes and limits
@pytest.mark.parametrize("params,spp,needle", [
    ({}, 10 ** 6, r"spp=1000000 x iterations=16 = 16000000 iterations exceed the maximum of 1048576 per render"),
    ({"resolution": 50000}, 1, r"resolution=50000: resolution\^2 lines per chain exceed 2\^31"),
    ({"max_depth": 100}, 1, r"max_depth=100: .* valid range: -1 \(unbounded\) or 0 .. 64")])
def test_sizes_beyond_the_maxima_are_refused_before_work(params, spp, needle):
    """Every size a user can ask for has a documented maximum, checked before anything is
    allocated: spp 10^6 used to precompute every global direction (25 GB) and hang."""
    scene = analytic.furnace(0.5, 0.5, "box", resolution=4).scene(dict(rb(8), **params))
    with pytest.raises(ValueError, match=needle):
        scene.integrator().render(scene, 0, seed=0, spp=spp)


def test_a_patch_table_beyond_the_memory_is_refused_before_it_is_built(monkeypatch):
    """A tiny patch_size: the patch count is predicted from the meshes before the table is
    built; beyond the available memory a clear error."""
    from mi_plugins.integrators.ray_bundle import integrator as module
    from mi_plugins.integrators.ray_bundle import memory
    scene = analytic.furnace(0.5, 0.5, "box", resolution=4).scene(dict(rb(8), patch_size=0.01, subdivide=True))
    assert memory.predicted_patches(scene, 0.01, True) == 12 * 64 * 64        # MAX_SPLIT per triangle
    monkeypatch.setattr(module, "available_memory", lambda: 1_000_000)
    with pytest.raises(MemoryError, match=r"divides into 49152 patch sides, whose table needs about 0.03 GB"):
        scene.integrator().render(scene, 0, seed=0, spp=1)


def test_camera_passes_split_into_groups_that_fit(monkeypatch):
    """A camera pass takes one sample per pixel and chain; where they would not fit (a
    quarter of the memory) the chains are split into groups, one pass each: the image
    stays exact (furnace), with 16 chains in groups of 2 here."""
    from mi_plugins.integrators.ray_bundle import integrator as module
    from mi_plugins.integrators.ray_bundle import memory
    per_group = 2 * 8 * 8 * memory.BYTES_PER_CAMERA_SAMPLE
    monkeypatch.setattr(module, "available_memory", lambda: 4 * per_group + 1)
    monkeypatch.setattr(memory, "check", lambda *a, **k: 0)        # the chains themselves "fit"
    case = analytic.furnace(0.5, 0.5, "box", resolution=8)
    scene = case.scene(rb(16, first_shot=True, average_diffuse=True))
    mi.render(scene, spp=1, seed=1)
    assert scene.integrator().camera_group == 2
    out = analytic.check(case, rb(16, first_shot=True, average_diffuse=True), spp=1, runs=16, seed=3)
    assert out.passed, out


def test_directions_come_in_bounded_blocks():
    """The directions of a render are made a block at a time: a stream for 10^7 iterations
    of 64 chains holds at most BLOCK iterations."""
    from mi_plugins.integrators.ray_bundle.directions import BLOCK, DirectionStream
    for kind in ("independent", "halton", "hammersley", "pi"):
        stream = DirectionStream(kind, 64, budget.rng(9), stratify=kind == "independent", antipodal=True,
                                 count=10 ** 7)
        dirs = [stream.next() for _ in range(3)]
        assert stream.buffer.shape[0] <= BLOCK and dirs[0].shape == (64, 3)
        assert np.allclose(np.linalg.norm(np.array(dirs), axis=-1), 1.0, atol=1e-6)


# ------------------------------------------------------------------ frozen steps
def test_steps_are_recorded_once_and_replayed():
    """Each kind of step (burn-in, averaged iteration, camera pass) is recorded once and
    replayed, also by the next render of the same scene; a replay gives the plain
    (traced) render's image for the same seed."""
    from mi_plugins.integrators.ray_bundle import frozen
    scene = analytic.furnace(0.5, 0.5, "box", resolution=8).scene(rb(8, first_shot=True, average_diffuse=True))
    integ = scene.integrator()
    a = np.array(mi.render(scene, spp=1, seed=3))
    b = np.array(mi.render(scene, spp=1, seed=3))
    advance, image = integ.step_cache.steps[integ.step_cache.last + (True,)]
    assert (advance.recordings, image.recordings) == (2, 1) and integ.step_cache.last not in integ.step_cache.unfrozen
    try:
        frozen.ENABLED = False
        plain = np.array(mi.render(analytic.furnace(0.5, 0.5, "box", resolution=8).scene(
            rb(8, first_shot=True, average_diffuse=True)), spp=1, seed=3))
    finally:
        frozen.ENABLED = True
    assert_same_image(a, b)
    assert_same_image(a, plain)


def test_a_later_render_keeps_the_arrays_an_earlier_one_made_its_own():
    """The first render copies the patch table's arrays mapped from numpy into memory of
    Dr.Jit's own (a frozen step compiles for the alignment it saw); the next render of the
    same scene keeps those copies instead of copying them again (0.34 s a render on a
    million triangles), and an array in numpy's memory is still copied."""
    from mi_plugins.integrators.ray_bundle import frozen
    scene = analytic.furnace(0.5, 0.5, "box", resolution=8).scene(rb(8, first_shot=True, average_diffuse=True))
    integ = scene.integrator()
    mi.render(scene, spp=1, seed=1)
    table = integ.patch_table(scene)
    arrays = lambda: {k: v for k, v in vars(table).items() if v is not None and dr.is_jit_v(v) and dr.width(v) > 1}
    first = arrays()
    assert len(first) >= 5
    mi.render(scene, spp=1, seed=2)
    again = arrays()
    assert all(again[k] is v for k, v in first.items()), sorted(k for k, v in first.items() if again[k] is not v)
    buffer = np.zeros(1001, dtype=np.float32)
    mapped = mi.Float(buffer[1:])                   # 4 bytes past numpy's (at least 16-byte) alignment
    copy = frozen._owned(mapped)
    dr.eval(copy)
    assert copy is not mapped and frozen._owned(copy) is copy and frozen._aligned(copy)
    assert not frozen._aligned(mapped)


def test_a_replayed_step_follows_scene_edits():
    """A later render of an edited scene (a BSDF value, a shape moved) gives what a fresh
    integrator gives: the steps read the scene's arrays as inputs, and a change of the
    values they bake (the bounding sphere) records them again."""
    d = analytic.furnace(0.5, 0.5, "box", resolution=8).scene_dict(rb(8, first_shot=True, average_diffuse=True))
    scene = mi.load_dict(d)
    mi.render(scene, spp=1, seed=1)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("reflectance.value"))
    params[key] = mi.Color3f(0.3, 0.4, 0.5)
    vkey = next(k for k in params.keys() if k.endswith("vertex_positions"))
    params[vkey] = params[vkey] * 1.1
    params.update()
    edited = np.array(mi.render(scene, spp=1, seed=2))
    fresh = np.array(mi.render(scene, integrator=mi.load_dict(rb(8, first_shot=True, average_diffuse=True)),
                               spp=1, seed=2))
    assert_same_image(edited, fresh)


# ------------------------------------------------------------------ finite depth, convergence
@pytest.mark.parametrize("depth", [1, 2, 3, 5])
def test_max_depth_truncates_as_path_does(depth):
    """max_depth keeps the bounce orders apart: the furnace box's exact truncated radiance
    (Mitsuba's meaning: 1 = emission only)."""
    out = check("furnace_box", rb(16, first_shot=True, average_diffuse=True, max_depth=depth), 16, 8, seed=8)
    assert out.passed, out


def test_albedo_one_room_at_the_defaults_extends_its_burn_in():
    """constant_lightsource_sierpinski (separable BSDFs, albedo 1 where nothing is emitted,
    directional_area emitters): at the default 16 iterations the average was 18 % low
    (1.64 against 2) and nothing said so. The chains' reflected share of their power
    gives the contraction ratio, and the burn-in goes on until the predicted bias is
    below 1 % (up to 8x the planned iterations); with adaptive=false a warning names the
    bias. Measured per-run SD 4 %: 8 runs of 4 x 4 pixels (the constant image), z 4.5 on
    their SE (about 6 %) plus the 1 % tolerance: the former -18 % is far outside."""
    case = analytic.cases()["constant_lightsource_sierpinski"](resolution=4)
    scene = case.scene({"type": "ray_bundle"})
    means = np.array([np.array(mi.render(scene, spp=1, seed=budget.seed(40 + k))).mean() for k in range(8)])
    assert scene.integrator().progress.total > 24        # the burn-in was extended
    se = means.std(ddof=1) / np.sqrt(len(means))
    budget.close(means.mean(), 2.0, se, slack=0.02, what="albedo-1 room, defaults")
    assert abs(means.mean() / 2.0 - 1) < 0.09, means.mean()
    scene = case.scene({"type": "ray_bundle", "adaptive": False})
    with pytest.warns(RuntimeWarning, match=r"not converged after a burn-in of 8 iterations: .* about \d+(\.\d+)? % "
                                            r"too low"):
        mi.render(scene, spp=1, seed=budget.seed(40))


def test_a_burn_in_beyond_max_iterations_is_refused_not_averaged():
    """The same room with max_iterations below what its burn-in needs: refused, naming the
    iterations the prediction asks for, before they are run (formerly a warning and an
    image 9.6 % too dark, z -6.3, in such a room). The test of the test is the one above:
    with the default limit the same room renders and matches its exact radiance."""
    case = analytic.cases()["constant_lightsource_sierpinski"](resolution=4)
    scene = case.scene({"type": "ray_bundle", "max_iterations": 24})
    with pytest.raises(errors.NotConverged, match=r"^ray_bundle: not converged within max_iterations=24: after a "
                                                   r"burn-in of 8 iterations .* it needs about (\d+) iterations") \
            as info:
        mi.render(scene, spp=1, seed=budget.seed(40))
    assert info.value.needed > 24 and scene.integrator().progress.total <= 24, info.value


def test_the_default_patch_size_sees_merged_meshes():
    """mi.load_dict merges shapes that share a BSDF into one Mesh whose bbox() is invalid
    and that scene.bbox() leaves out: the open many-emitter scene's two 80 x 80 planes
    vanished from it, the default patch size came out 7x too small and the planes split
    into 16384 patches (the table 16731). The scene's bounds now come from its shapes."""
    from mi_plugins.verify.coverage import rows
    from mi_plugins.integrators.ray_bundle.memory import predicted_patches
    from mi_plugins.base.queries import scene_bounds
    scene = mi.load_dict(rows.open_many_emitters(8))
    lo, hi = scene_bounds(scene)
    assert np.allclose(lo, -40) and np.allclose(hi, 40), (lo, hi)
    assert float(dr.norm(scene.bbox().extents())) < 40          # Mitsuba's box misses the planes
    integ = mi.load_dict({"type": "ray_bundle"})
    patches = predicted_patches(scene, integ.patch_size_for(scene), True)
    assert 300 < patches < 2000, patches


def test_sky_light_is_not_mistaken_for_unconverged_interreflection():
    """first_shot=false under a constant sky: the sky's light reflected once arrives in
    full from the first iteration; the convergence model must not read it as a reflected
    part still growing (it warned 'not converged' and extended the burn-in 8x). A floor
    under a sky of radiance 1 reflects 0.5 (albedo 0.5, the whole hemisphere open)."""
    import warnings
    scene = mi.load_dict({
        "type": "scene",
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}},
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
        "sensor": {"type": "perspective", "fov": 20, "to_world": mi.ScalarTransform4f().look_at(
            origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}}}})
    integ = mi.load_dict({"type": "ray_bundle", "first_shot": False, "chains": 8, "resolution": 16,
                          "iterations": 8, "burn_in": 4})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        means = [float(np.mean(np.array(mi.render(scene, integrator=integ, spp=1, seed=s))[..., :3]))
                 for s in range(4)]
    assert not [str(w.message) for w in caught if "converge" in str(w.message) or "burn" in str(w.message)]
    se = np.std(means, ddof=1) / np.sqrt(len(means))
    assert abs(np.mean(means) - 0.5) < 4 * se + 0.005, (means, se)


def test_the_display_modes_solve_grows_with_the_camera_samples():
    """Where a render's camera samples ask for more than ``iterations``, a display mode's
    default solve runs LINES_PER_CAMERA_SAMPLE bundle lines for each (rounded up to an
    eighth of a power of two), so that more spp lowers the solve's noise too; smaller
    budgets share the solve of ``iterations``, one budget's renders share theirs; a given
    ``iterations``, the gather and a solve asked for (``mi_plugins.solve``: it serves every
    budget) keep their counts. The test of the test: the first budget above ``iterations``
    solves anew."""
    from mi_plugins.integrators.ray_bundle.integrator import LINES_PER_CAMERA_SAMPLE
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = 16
    scene = mi.load_dict(d)
    small = {"type": "ray_bundle", "display": "smooth", "patch_size": 0.5, "resolution": 8, "chains": 4}
    integrator = mi.load_dict(small)
    lines = 8 * 8 * 4                     # per iteration; 16 iterations: 4096 lines, 0.25 x 64 x 256 samples
    assert LINES_PER_CAMERA_SAMPLE * 64 * 256 == 16 * lines
    counts = []
    for spp in (16, 64, 128, 128, 256, 72):
        mi.render(scene, integrator=integrator, spp=spp, seed=budget.seed(0))
        counts.append((integrator.counts(1)[0], integrator.solve_count))
    assert counts == [(16, 1), (16, 1), (32, 2), (32, 2), (64, 3), (18, 4)], counts
    solved = integrator.solve(scene, seed=budget.seed(0))          # (it serves every budget)
    mi.render(scene, integrator=integrator, spp=256, seed=budget.seed(0))
    assert integrator.solve_count == 5 and integrator.last_solution.meta is solved.meta
    for params in (dict(small, iterations=16), dict(small, display="gather")):
        other = mi.load_dict(params)
        mi.render(scene, integrator=other, spp=4 if params["display"] == "gather" else 256, seed=budget.seed(0))
        assert other.counts(1)[0] == 16, (params, other.counts(1))
