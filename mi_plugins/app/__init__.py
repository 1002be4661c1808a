"""The applications on top of the package: :mod:`.cli` (``mi-plugins``), :mod:`.demo`,
:mod:`.passes` (rendering in passes with progress and Ctrl-C), :mod:`.exr` (EXR files with
metadata), :mod:`.reference` (the plugin reference generated from the docstrings).

Rule: may import every other part of the package.
"""
