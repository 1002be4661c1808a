"""Package set-up: registration, variant errors, LLVM detection, layout."""
import os

import pytest

import mitsuba as mi
import mi_plugins
from mi_plugins.base import llvm
from mi_plugins import registry

from conftest import REPO, run_python, scalar_variant_refusal

#: the package's public plugins, written out independently of the folders' PLUGINS tables
EXPECTED_PLUGINS = {
    "integrator": ["qmc_lighttrace", "ray_bundle", "stochastic_ray"],
    "bsdf": ["phong", "separable"],
    "emitter": ["directional_area", "simulated_area"],
    "sampler": ["cmj", "faure", "halton", "lattice", "padded_sobol", "sobol", "zsobol"],
}


def test_every_plugin_is_registered_and_loads():
    """register() reports exactly the public plugins, and each one loads through
    Mitsuba's plugin manager (mi.load_dict) as the class its folder names."""
    registered = mi_plugins.register()
    assert {k: sorted(v) for k, v in registered.items()} == EXPECTED_PLUGINS
    table = registry.plugin_table()
    minimal = {"simulated_area": {"target_radiance": 1.0}, "separable": {"target_radiance": 1.0}}
    for kind, names in EXPECTED_PLUGINS.items():
        for name in names:
            d = dict({"type": name}, **minimal.get(name, {}))
            if kind == "emitter":   # area emitters need a shape
                obj = mi.load_dict({"type": "rectangle", "emitter": d}).emitter()
            else:
                obj = mi.load_dict(d)
            assert type(obj).__name__ == table[kind][name].split(":")[1], (name, type(obj))


@pytest.mark.parametrize("integrator", EXPECTED_PLUGINS["integrator"])
def test_integrators_refuse_a_scalar_variant_themselves(integrator):
    """Registered for scalar_rgb regardless of register()'s refusal, each integrator's
    constructor refuses the variant with a message naming it and a supported one."""
    refused, out = scalar_variant_refusal(integrator)
    assert refused and "%s: variant 'scalar_rgb' is not supported" % integrator in out and "llvm_ad_rgb" in out, out


def test_import_without_variant_names_supported_variants():
    r = run_python("import mi_plugins")
    assert r.returncode != 0
    assert "no Mitsuba variant is set" in r.stderr and "llvm_ad_rgb" in r.stderr


def test_import_with_scalar_variant_is_refused():
    r = run_python("import mitsuba as mi; mi.set_variant('scalar_rgb'); import mi_plugins")
    assert r.returncode != 0
    assert "variant 'scalar_rgb' is not supported" in r.stderr and "llvm_ad_rgb" in r.stderr


def test_variant_switch_refuses_mono_and_reregisters_rgb():
    code = ("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import mi_plugins\n"
            "mi.set_variant('llvm_ad_mono')\n"
            "try:\n    mi_plugins.register()\nexcept mi_plugins.VariantError as e:\n    print('REFUSED', e)\n"
            "mi.set_variant('llvm_ad_rgb'); r = mi_plugins.register()\n"
            "from mi_plugins import analytic\n"
            "res = analytic.check(analytic.furnace(resolution=8), 'path', spp=4, runs=16)\n"
            "print('OK', res.passed, sorted(sum(r.values(), [])))")
    r = run_python(code)
    assert r.returncode == 0, r.stderr
    assert "REFUSED mi_plugins: variant 'llvm_ad_mono' is not supported" in r.stdout
    assert "OK True" in r.stdout


def test_old_llvm_gives_clear_error():
    old = [p for p in ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1", "/usr/lib/x86_64-linux-gnu/libLLVM-15.so")
           if os.path.exists(p)]
    if not old:
        pytest.skip("no LLVM 15 library on this machine to simulate an old LLVM")
    r = run_python("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import mi_plugins",
                   env={"DRJIT_LIBLLVM_PATH": old[0]})
    assert r.returncode != 0
    assert "needs LLVM >= 19" in r.stderr and "libllvm19" in r.stderr


def test_find_libllvm_returns_a_recent_version():
    path = llvm.find_libllvm()
    assert path is not None and llvm._major(path) >= llvm.MIN_LLVM_MAJOR


def test_plugin_folders_import_as_subpackages_only(tmp_path):
    # Run outside the checkout: the generic folder names must not be importable.
    r = run_python("import importlib.util as u, mitsuba as mi; mi.set_variant('llvm_ad_rgb');"
                   "import mi_plugins.integrators, mi_plugins.bsdfs;"
                   "print([u.find_spec(n) is None for n in ('integrators', 'bsdfs', 'emitters', 'samplers')])",
                   cwd=str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "[True, True, True, True]" in r.stdout


def test_pyproject_maps_plugin_folders_into_the_package():
    text = open(os.path.join(REPO, "pyproject.toml")).read()
    for folder in ("integrators", "bsdfs", "emitters", "samplers"):
        assert '"mi_plugins.%s" = "%s"' % (folder, folder) in text
