import os
import subprocess
import sys

import pytest

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import mi_plugins  # noqa: E402,F401  (registers the plugins)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_python(code, env=None, cwd=None):
    """Run a snippet in a fresh interpreter (variant state is process-global)."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=full_env,
                          cwd=cwd or REPO, timeout=300)


@pytest.fixture(autouse=True)
def _primary_variant():
    if mi.variant() != "llvm_ad_rgb":
        mi.set_variant("llvm_ad_rgb")
        mi_plugins.register()
    yield
