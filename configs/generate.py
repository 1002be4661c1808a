"""Regenerate the XML scene files of this folder from mi_plugins.verify.analytic.

    python3 configs/generate.py          # all cases of analytic.cases()

Each file states its exact radiance in its header comment; tests/test_configs.py
checks that the files are up to date and that they load and render correctly.
"""
import os
import sys

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
from mi_plugins.verify.analytic import export  # noqa: E402

if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    for path in export.export_all(here, sys.argv[1:] or None):
        print("wrote", os.path.relpath(path))
