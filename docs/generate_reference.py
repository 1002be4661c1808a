"""Write the plugin reference (docs/reference.md) from the plugins' class docstrings.

    python3 docs/generate_reference.py           # rewrite the generated part of docs/reference.md
    python3 docs/generate_reference.py --check   # exit 1 when docs/reference.md is stale

The docstring style and the conversion are described in ``mi_plugins/app/reference.py``;
tests/test_docs.py runs the check.
"""
import os
import sys

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
from mi_plugins.app import reference  # noqa: E402

README = os.path.join(os.path.dirname(os.path.abspath(__file__)), "reference.md")

if __name__ == "__main__":
    with open(README) as f:
        text = f.read()
    if "--check" in sys.argv[1:]:
        if reference.readme_block(text) != reference.markdown():
            sys.exit("docs/reference.md is stale: run `python3 docs/generate_reference.py`")
        print("docs/reference.md is up to date")
    else:
        with open(README, "w") as f:
            f.write(reference.update_readme(text))
        print("wrote the plugin reference of", os.path.relpath(README))
