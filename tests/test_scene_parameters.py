"""Scene parameters (``mi.traverse``) of the package's BSDFs and emitters: the keys and
flags each plugin exposes; every exposed parameter edited through
``params[key] = value; params.update()`` renders the same image (same seed) as a scene
loaded with that value; edits are re-checked like values at load (same ParameterError
messages) and an invalid edit is undone (the scene renders as before it); an edited
value does not recompile kernels; forward-mode AD through ``prb`` gives a finite,
non-zero gradient image for every differentiable parameter. Tests of the tests: the old
and new values of every edit give different images, and an emitter that skips its
``parameters_changed`` fails the comparison.

One small scene holds every plugin: a ``phong`` floor, a lamp (``directional_area``
emission, ``separable`` BSDF referencing it) facing down, and a diffuse back wall with
``simulated_area`` emission; 16 x 16 pixels.
"""
import gc
from unittest import mock

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import budget
from mi_plugins.base.params import ParameterError

D, ND, DISC = mi.ParamFlags.Differentiable, mi.ParamFlags.NonDifferentiable, mi.ParamFlags.Discontinuous
SPP = 4


@pytest.fixture(autouse=True)
def _release_scenes():
    # Dr.Jit traces every live plugin instance of a kind in each render: release this
    # test's scenes before the next test.
    yield
    gc.collect()


def scene(floor=None, lamp=None, lamp_bsdf=None, wall=None, wall_bsdf=None):
    """The test scene; each argument updates one plugin dict (floor: phong, lamp:
    directional_area, lamp_bsdf: separable, wall: simulated_area, wall_bsdf: diffuse)."""
    T = mi.ScalarTransform4f
    phong = {"type": "phong", "diffuse_reflectance": 0.4, "specular_reflectance": 0.3, "exponent": 10.0}
    emitter = {"type": "directional_area", "id": "lamp_emission", "radiance": 1.0, "exponent": 2.0}
    separable = {"type": "separable", "target_radiance": 3.0, "emission": {"type": "ref", "id": "lamp_emission"}}
    simulated = {"type": "simulated_area", "target_radiance": 0.5}
    diffuse = {"type": "diffuse", "reflectance": 0.5}
    for d, extra in ((phong, floor), (emitter, lamp), (separable, lamp_bsdf), (simulated, wall), (diffuse, wall_bsdf)):
        d.update(extra or {})
    if emitter.get("profile") == "tabulated":
        emitter.pop("exponent", None)
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 5},
        "sensor": {"type": "perspective", "to_world": T().look_at([0, -3, 0.8], [0, 0, 0.6], [0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": SPP}},
        "floor": {"type": "rectangle", "to_world": T().scale(2), "bsdf": phong},
        "lamp": {"type": "rectangle", "to_world": T().translate([0, 0, 1.5]).rotate([1, 0, 0], 180).scale(0.5),
                 "emitter": emitter, "bsdf": separable},
        "wall": {"type": "rectangle", "to_world": T().translate([0, 1.5, 1]).rotate([1, 0, 0], 90).scale(2),
                 "bsdf": diffuse, "emitter": simulated},
    }, optimize=False)


def render(s):
    """The image (numpy) of scene ``s`` with the suite's seed 0. The random salts of
    the plugins that draw numbers inside ``eval`` restart, so that equal scenes give equal
    images whatever was rendered before."""
    for obj in list(s.emitters()) + [shape.bsdf() for shape in s.shapes()]:
        if hasattr(obj, "salt"):
            obj.salt.count = 0
    return np.array(mi.render(s, seed=budget.seed(0), spp=SPP))


def edited(key, value, **loaded):
    """Scene loaded with ``loaded``, then ``key`` set to ``value`` through mi.traverse."""
    s = scene(**loaded)
    params = mi.traverse(s)
    params[key] = value
    params.update()
    return s


def same(a, b):
    return np.allclose(a, b, rtol=1e-5, atol=1e-7)


# ------------------------------------------------------------------ keys and flags
EXPOSED = {
    "floor.bsdf.diffuse_reflectance.value": (D, mi.Float),
    "floor.bsdf.specular_reflectance.value": (D, mi.Float),
    "floor.bsdf.exponent": (D | DISC, mi.Float),
    "lamp.bsdf.target_radiance": (D, mi.Color3f),
    "lamp.emitter.radiance.value": (D, mi.Float),
    "lamp.emitter.exponent": (D | DISC, mi.Float),
    "lamp.emitter.sampling_weight": (ND, float),          # Mitsuba's Emitter base class
    "wall.emitter.target_radiance": (D, mi.Color3f),
    "wall.emitter.sampling_weight": (ND, float),
}


def test_keys_flags_and_types_of_every_plugin():
    params = mi.traverse(scene())
    ours = {k: (params.flags(k), type(params[k])) for k in params.keys()
            if k.startswith(("floor.bsdf.", "lamp.bsdf.", "lamp.emitter.", "wall.emitter."))}
    assert ours == {k: (+flags, t) for k, (flags, t) in EXPOSED.items()}
    tabulated = mi.traverse(scene(lamp={"profile": "tabulated", "values": "1, 0.5, 0.2"}))
    assert "lamp.emitter.exponent" not in tabulated
    assert tabulated.flags("lamp.emitter.values") == +(D | DISC) and type(tabulated["lamp.emitter.values"]) is mi.Float
    assert dr.width(tabulated["lamp.emitter.values"]) == 3


# ------------------------------------------------------------------ edits render like loads
#: (id, key, old loaded, new value through traverse, new loaded): every exposed parameter
EDITS = [
    ("phong-exponent", "floor.bsdf.exponent", {}, 40.0, {"floor": {"exponent": 40.0}}),
    ("phong-kd", "floor.bsdf.diffuse_reflectance.value", {}, 0.6, {"floor": {"diffuse_reflectance": 0.6}}),
    ("phong-ks", "floor.bsdf.specular_reflectance.value", {}, 0.1, {"floor": {"specular_reflectance": 0.1}}),
    ("phong-kd-texture", "floor.bsdf.diffuse_reflectance.color0.value",
     {"floor": {"diffuse_reflectance": {"type": "checkerboard", "color0": 0.1, "color1": 0.6}}}, 0.5,
     {"floor": {"diffuse_reflectance": {"type": "checkerboard", "color0": 0.5, "color1": 0.6}}}),
    ("separable-target", "lamp.bsdf.target_radiance", {}, mi.Color3f(1.5, 2.0, 6.0),
     {"lamp_bsdf": {"target_radiance": [1.5, 2.0, 6.0]}}),
    ("directional-radiance", "lamp.emitter.radiance.value", {}, 1.4, {"lamp": {"radiance": 1.4}}),
    ("directional-exponent", "lamp.emitter.exponent", {}, 6.0, {"lamp": {"exponent": 6.0}}),
    ("directional-values", "lamp.emitter.values", {"lamp": {"profile": "tabulated", "values": "1, 0.5, 0.2"}},
     mi.Float([0.2, 1.0, 0.7]), {"lamp": {"profile": "tabulated", "values": "0.2, 1.0, 0.7"}}),
    ("directional-values-resized", "lamp.emitter.values", {"lamp": {"profile": "tabulated", "values": "1, 0.5, 0.2"}},
     mi.Float([0.3, 1.2, 0.9, 0.1]), {"lamp": {"profile": "tabulated", "values": "0.3, 1.2, 0.9, 0.1"}}),
    ("simulated-target", "wall.emitter.target_radiance", {}, 0.8, {"wall": {"target_radiance": 0.8}}),
    # the emission follows an edit of the BSDF below it (estimated at every evaluation)
    ("simulated-under-edited-bsdf", "wall.bsdf.reflectance.value", {}, 0.2, {"wall_bsdf": {"reflectance": 0.2}}),
]


@pytest.mark.parametrize("key, old, value, new", [e[1:] for e in EDITS], ids=[e[0] for e in EDITS])
def test_an_edited_parameter_renders_like_a_loaded_one(key, old, value, new):
    img_edited = render(edited(key, value, **old))
    img_new = render(scene(**new))
    img_old = render(scene(**old))
    assert same(img_edited, img_new), np.abs(img_edited - img_new).max()
    # test of the test: the edit changes the image, so an ignored edit would fail above
    assert np.abs(img_old - img_new).max() > 1e-3 * np.abs(img_new).max()


def test_the_comparison_sees_an_emitter_that_skips_parameters_changed():
    """Test of the test: an emitter whose parameters_changed does nothing still sees the
    new exponent in its own kernels (the value is edited in place), but the separable
    BSDF's normalization integral and sampling table stay stale: the comparison fails."""
    s = scene()
    cls = type(next(e for e in s.emitters() if hasattr(e, "profile")))
    with mock.patch.object(cls, "parameters_changed", lambda self, keys=(): None):
        params = mi.traverse(s)
        params["lamp.emitter.exponent"] = 6.0
        params.update()
    assert not same(render(s), render(scene(lamp={"exponent": 6.0})))


# ------------------------------------------------------------------ invalid edits
TABULATED = {"lamp": {"profile": "tabulated", "values": "1, 0.5, 0.2"}}
TEXTURED = {"floor": {"diffuse_reflectance": {"type": "checkerboard", "color0": 0.1, "color1": 0.6}}}
EMITTER = "emission=<DirectionalAreaEmitter id='lamp_emission'>"
SEPARABLE_RULE = ("are invalid together; valid range: target_radiance must exceed the maximum emission %s of the "
                  "surface in every channel (otherwise the BSDF would be negative)")
TEXTURE_RANGE = "valid range: a float, an RGB triple or a texture, finite and >= 0 everywhere"
INVALID = [
    ("floor.bsdf.exponent", -1.0, {},
     "phong: parameter exponent=-1.0 is invalid; valid range: a finite number >= 0"),
    ("floor.bsdf.diffuse_reflectance.value", 0.8, {},
     "phong: parameters diffuse_reflectance=0.8, specular_reflectance=0.3 are invalid together; valid range: "
     "diffuse_reflectance + specular_reflectance <= 1 in every channel for an energy-conserving BSDF "
     "(the sum reaches 1.1)"),
    ("floor.bsdf.specular_reflectance.value", float("nan"), {},
     "phong: parameter specular_reflectance=nan is invalid; " + TEXTURE_RANGE),
    ("floor.bsdf.diffuse_reflectance.color1.value", -0.2, TEXTURED,
     "phong: parameter diffuse_reflectance=<Checkerboard> is invalid; " + TEXTURE_RANGE +
     " (the texture reaches [-0.2, 0.1])"),
    ("lamp.bsdf.target_radiance", mi.Color3f(0.9, 2.0, 2.0), {},
     "separable: parameters target_radiance=[0.9, 2.0, 2.0], %s %s" % (EMITTER, SEPARABLE_RULE % 1)),
    ("lamp.emitter.radiance.value", 3.5, {},        # the separable BSDF's rule, checked on the emitter's edit
     "separable: parameters target_radiance=3.0, %s %s" % (EMITTER, SEPARABLE_RULE % 3.5)),
    ("lamp.emitter.radiance.value", -0.5, {},
     "directional_area: parameter radiance=-0.5 is invalid; " + TEXTURE_RANGE),
    ("lamp.emitter.exponent", float("inf"), {},
     "directional_area: parameter exponent=inf is invalid; valid range: a finite number >= 0"),
    ("lamp.emitter.values", mi.Float([0.0, 0.0, 0.0]), TABULATED,
     "directional_area: parameter values='0.0, 0.0, 0.0' is invalid; valid range: a string of at least 2 "
     "comma-separated finite numbers >= 0, not all 0 (these values emit nothing)"),
    ("wall.emitter.target_radiance", mi.Color3f(0.5, 0.0, 0.5), {},
     "simulated_area: parameter target_radiance=[0.5, 0.0, 0.5] is invalid; valid range: a float or an RGB "
     "triple, finite and > 0 in every channel"),
]


@pytest.mark.parametrize("key, value, loaded, message", INVALID, ids=["%s=%s" % (k, v) for k, v, _, _ in INVALID])
def test_an_invalid_edit_raises_and_is_undone(key, value, loaded, message):
    """update() raises the load-time message; the parameter shows its previous value
    again and the scene renders the freshly loaded image."""
    s = scene(**loaded)
    params = mi.traverse(s)
    valid = np.array(params[key])
    params[key] = value
    with pytest.raises(ParameterError) as info:
        params.update()
    assert str(info.value) == message
    assert np.array_equal(np.array(params[key]), valid)
    assert same(render(s), render(scene(**loaded)))


@pytest.mark.parametrize("first", ["lamp.bsdf.target_radiance", "lamp.emitter.radiance.value"])
def test_edits_valid_alone_but_invalid_together_are_undone_together(first):
    """L~ = 2 (valid with radiance 1) and radiance 2.5 (valid with L~ = 3) in one update:
    refused whichever plugin is updated first, and both are undone."""
    s = scene()
    params = mi.traverse(s)
    edits = {"lamp.bsdf.target_radiance": 2.0, "lamp.emitter.radiance.value": 2.5}
    for key in sorted(edits, key=lambda k: k != first):
        params[key] = edits[key]
    with pytest.raises(ParameterError, match="maximum emission 2.5 of the surface"):
        params.update()
    assert np.allclose(np.array(params["lamp.bsdf.target_radiance"]).ravel(), 3.0)
    assert np.allclose(np.array(params["lamp.emitter.radiance.value"]), 1.0)
    assert same(render(s), render(scene()))


# ------------------------------------------------------------------ no recompilation
def _kernels(s):
    dr.kernel_history()                       # clears the history
    render(s)
    return sorted(k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT)


def test_an_edit_reuses_the_compiled_kernels():
    """Scalars and colours are opaque JIT values: an edit changes kernel inputs, not the
    kernels. Test of the test: a literal written past parameters_changed is compiled
    into a new kernel."""
    s = scene()
    params = mi.traverse(s)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        before = _kernels(s)
        for key, value in [("floor.bsdf.exponent", 20.0), ("floor.bsdf.diffuse_reflectance.value", 0.5),
                           ("lamp.bsdf.target_radiance", 4.0), ("lamp.emitter.exponent", 3.0),
                           ("lamp.emitter.radiance.value", 1.2), ("wall.emitter.target_radiance", 0.7)]:
            params[key] = value
        params.update()
        assert _kernels(s) == before
        next(sh for sh in s.shapes() if sh.id() == "floor").bsdf().m_exponent = mi.Float(30.0)
        assert _kernels(s) != before
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)


# ------------------------------------------------------------------ forward-mode AD
AD = [("floor.bsdf.exponent", {}), ("floor.bsdf.diffuse_reflectance.value", {}),
      ("floor.bsdf.specular_reflectance.value", {}), ("floor.bsdf.diffuse_reflectance.color0.value", TEXTURED),
      ("lamp.bsdf.target_radiance", {}), ("lamp.emitter.radiance.value", {}), ("lamp.emitter.exponent", {}),
      ("lamp.emitter.values", TABULATED), ("wall.emitter.target_radiance", {})]


@pytest.mark.parametrize("key, loaded", AD, ids=[k for k, _ in AD])
def test_forward_mode_gradient_is_finite_and_nonzero(key, loaded):
    """dr.forward through mi.render with 'prb' (derived quantities recomputed by update()
    with the gradient enabled): a finite gradient image, not zero where the parameter
    acts (at least 0.1 % of the image's mean, on average)."""
    s = scene(**loaded)
    params = mi.traverse(s)
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(s, params, seed=budget.seed(1), spp=SPP, integrator=mi.load_dict({"type": "prb", "max_depth": 5}))
    dr.forward(params[key])
    grad = np.array(dr.grad(img))
    assert np.all(np.isfinite(grad))
    assert np.mean(np.abs(grad)) > 1e-3 * np.mean(np.array(img)), np.mean(np.abs(grad))
