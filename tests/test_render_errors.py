"""mi.render raises the package's own errors as they are (mi_plugins.base.render_errors): a
refusal's first line names the plugin, the feature and what to use instead, not
drjit.custom's generic wrapper; the errors of other integrators pass unchanged."""
import mitsuba as mi
import pytest

from mi_plugins.base import render_errors, errors
def _box(bsdf):
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = 8
    d["small-box"]["bsdf"] = bsdf
    return mi.load_dict(d)


@pytest.mark.parametrize("bsdf, lobe", [({"type": "conductor"}, "purely specular"),
                                        ({"type": "thindielectric"}, "null lobe"),
                                        ({"type": "mask", "opacity": 0.5, "bsdf": {"type": "diffuse"}}, "null lobe")])
def test_refusal_is_the_top_level_error(bsdf, lobe):
    scene = _box(bsdf)
    for call in (lambda: mi.render(scene, integrator=mi.load_dict({"type": "ray_bundle"}), spp=1),
                 lambda: mi.render(scene, None, 0, mi.load_dict({"type": "ray_bundle"}), spp=1)):
        with pytest.raises(errors.Unsupported) as info:
            call()
        first = str(info.value).splitlines()[0]
        assert first.startswith("ray_bundle: the BSDF '%s'" % bsdf["type"]) and lobe in first, first
        assert "; render this scene" in first or "use" in first, first


def test_scene_integrator_errors_are_unwrapped_too():
    d = mi.cornell_box()
    d["sensor"]["film"]["width"] = d["sensor"]["film"]["height"] = 8
    d["small-box"]["bsdf"] = {"type": "conductor"}
    d["integrator"] = {"type": "ray_bundle"}
    with pytest.raises(errors.Unsupported, match="^ray_bundle: the BSDF 'conductor'"):
        mi.render(mi.load_dict(d), spp=1)


class _Foreign(mi.SamplingIntegrator):
    """An integrator of somebody else's package whose render raises."""

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        raise ValueError("foreign failure")


def test_other_errors_pass_unchanged():
    """The test of the test: another package's integrator keeps Mitsuba's behaviour (the
    wrapper and the chained cause), so the unwrapping is the package's doing alone."""
    mi.register_integrator("mi_plugins_test_foreign", lambda props: _Foreign(props))
    scene = _box({"type": "diffuse"})
    with pytest.raises(RuntimeError, match=r"^drjit\.custom\(") as info:
        mi.render(scene, integrator=mi.load_dict({"type": "mi_plugins_test_foreign"}), spp=1)
    assert isinstance(info.value.__cause__, ValueError)
    assert render_errors.unwrapped(info.value, scene.integrator()) is None
    assert getattr(mi.render, "_mi_plugins_unwraps", False)
