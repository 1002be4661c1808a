"""mi_plugins: Mitsuba 3 plugins for stochastic iteration, quasi-Monte Carlo
light tracing and analytically verifiable test scenes.

Usage::

    import mitsuba as mi
    mi.set_variant('llvm_ad_rgb')
    import mi_plugins            # registers every plugin for the active variant

After switching variants, call :func:`mi_plugins.register` again.

Exception: when pytest loads the package's pytest plugin (``mi_plugins.verify.pytest_plugin``,
a ``pytest11`` entry point) before any Mitsuba variant is set, Python imports this
package as the plugin's parent *bare*: no Mitsuba import, no registration. The plugin
drops the bare package from ``sys.modules`` as soon as pytest registers it, so the next
``import mi_plugins`` (after ``mi.set_variant``) is the full import described above.
"""
import os
import sys


def _imported_bare():
    """True when this package is being imported only as the parent of its pytest plugin,
    inside a pytest process, with no Mitsuba variant set yet (the full import would raise
    VariantError there, and would cost every pytest session the Mitsuba start-up)."""
    if "_pytest" not in sys.modules:
        return False
    mitsuba = sys.modules.get("mitsuba")
    if mitsuba is not None and getattr(mitsuba, "variant", lambda: None)() is not None:
        return False
    target = __name__ + ".verify.pytest_plugin"
    frame = sys._getframe(1)
    while frame is not None:   # Python imports a package before its submodule
        if frame.f_code.co_name == "_find_and_load_unlocked" and frame.f_locals.get("name") == target:
            return True
        frame = frame.f_back
    return False


#: True while this module is the bare parent of the pytest plugin (see the module docstring)
_BARE = _imported_bare()

from mi_plugins.base import llvm  # noqa: E402

__version__ = "0.1.0"

#: Variants whose plugins are implemented (JIT, RGB). ``llvm_ad_rgb`` is the
#: primary, tested target; ``llvm_rgb`` is tested too; CUDA variants use the same code.
SUPPORTED_VARIANTS = ("llvm_ad_rgb", "llvm_rgb", "cuda_ad_rgb", "cuda_rgb")
PRIMARY_VARIANT = "llvm_ad_rgb"

llvm.configure()  # before Dr.Jit loads libLLVM


def _source_checkout_root():
    """The repository root when running from a source checkout, else None."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        with open(os.path.join(root, "pyproject.toml")) as f:
            is_ours = 'name = "mi-plugins"' in f.read()
    except OSError:
        return None
    return root if is_ours and os.path.isdir(os.path.join(root, "integrators")) else None


# In a source checkout the plugin folders sit beside this package; an installed
# package has them inside. Either way they import as mi_plugins.<folder>.
_ROOT = _source_checkout_root()
if _ROOT is not None and _ROOT not in __path__:
    __path__.append(_ROOT)

if not _BARE:
    import mitsuba as mi  # noqa: E402


class VariantError(ImportError):
    """The active Mitsuba variant is not one this package supports."""


def _launched_as_cli():
    prog = os.path.basename(sys.argv[0]) if sys.argv else ""
    orig = getattr(sys, "orig_argv", [])
    return prog == "mi-plugins" or (len(orig) >= 3 and orig[1] == "-m" and orig[2] == "mi_plugins")


def check_variant(variant=None):
    """Return the active variant, or raise VariantError naming the supported ones."""
    variant = variant if variant is not None else mi.variant()
    if variant is None:
        raise VariantError(
            "mi_plugins: no Mitsuba variant is set. Call mi.set_variant(...) with one of "
            "%s before `import mi_plugins` (primary: '%s')."
            % (", ".join(SUPPORTED_VARIANTS), PRIMARY_VARIANT))
    if variant not in SUPPORTED_VARIANTS:
        raise VariantError(
            "mi_plugins: variant '%s' is not supported; the plugins are vectorised Dr.Jit "
            "code for the JIT RGB variants %s (primary: '%s')."
            % (variant, ", ".join(SUPPORTED_VARIANTS), PRIMARY_VARIANT))
    if variant.startswith("llvm"):
        llvm.check_loaded()
    return variant


def register():
    """Register every plugin of the package for the active Mitsuba variant.

    Returns a dict ``{kind: [plugin names]}``. Call it again after
    ``mi.set_variant`` switches to another variant. Also makes ``mi.render`` raise the
    package's own exceptions as they are (:mod:`mi_plugins.base.render_errors`).
    """
    from mi_plugins import registry
    from mi_plugins.base import render_errors
    registered = registry.register_all(check_variant())
    render_errors.install()      # the package's errors reach mi.render's caller unwrapped
    return registered


def solve(scene, integrator=None, seed=0):
    """The view-independent solution (:class:`mi_plugins.solution.solution.Solution`) of ``scene`` by
    ``integrator`` ('ray_bundle' or 'qmc_lighttrace': a plugin dict, a loaded integrator,
    or None for the scene's own) with ``seed``. A loaded integrator keeps it: its next
    render of the scene with that seed, from any sensor, displays it without solving."""
    from mi_plugins.solution.integrator import SolutionIntegrator
    if integrator is None:
        integrator = scene.integrator()
    elif isinstance(integrator, dict):
        integrator = mi.load_dict(integrator)
    if not isinstance(integrator, SolutionIntegrator):
        raise TypeError("mi_plugins.solve: integrator %s has no view-independent solution; use 'ray_bundle' or "
                        "'qmc_lighttrace'" % (integrator.class_name() if hasattr(integrator, "class_name")
                                               else type(integrator).__name__))
    return integrator.solve(scene, seed)


def release():
    """Drop what the package keeps of the last scene it rendered (its patch tables and
    ``ray_bundle``'s recorded steps, kept so that the next view of the same scene starts at
    once), then collect the garbage: a scene the caller no longer holds is freed, with its
    plugins. Call it before rendering other scenes once done with one: Dr.Jit traces every
    live plugin in every vcall, so a kept scene makes later kernels larger, and one of its
    plugins that a later integrator cannot trace makes that render fail
    (:mod:`mi_plugins.base.caches`)."""
    from mi_plugins.base import caches
    caches.release()


#: shortcuts: ``from mi_plugins import analytic`` (the scenes whose exact radiance is known)
_SHORTCUTS = {"analytic": "mi_plugins.verify.analytic"}


def __getattr__(name):
    if name in _SHORTCUTS and not _BARE:
        import importlib
        return importlib.import_module(_SHORTCUTS[name])
    raise AttributeError("module 'mi_plugins' has no attribute '%s'" % name)


if _BARE:
    registered = {}
else:
    if mi.variant() is None and _launched_as_cli():
        mi.set_variant(PRIMARY_VARIANT)
    elif mi.variant() is None and os.environ.get("MI_PLUGINS_VARIANT"):
        # processes that import the package before any code of theirs runs, e.g. the Dask
        # workers of a distributed render, which unpickle their task functions from it
        mi.set_variant(os.environ["MI_PLUGINS_VARIANT"])

    registered = register()
    if __name__ + ".verify.pytest_plugin" in sys.modules:  # loaded earlier with a bare parent
        import importlib
        verify = importlib.import_module(__name__ + ".verify")
        verify.pytest_plugin = sys.modules[__name__ + ".verify.pytest_plugin"]
