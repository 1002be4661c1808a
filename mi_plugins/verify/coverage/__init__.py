"""The coverage matrix: every feature Mitsuba can put in a scene against every package
integrator, each cell right (PASS), refused clearly (REFUSED) or not applicable with its
reason (N/A). Rows are enumerated from the installed Mitsuba (:mod:`.catalog`); scenes
are in :mod:`.rows`, expectations in :mod:`.expected`, the runner in :mod:`.matrix`.
``mi-plugins verify --suite coverage`` runs it; ``docs/coverage.md`` holds the table.
"""
from mi_plugins.verify.coverage import catalog, expected, matrix, rows
from .matrix import Cell, run, run_all

__all__ = ["catalog", "expected", "matrix", "rows", "Cell", "run", "run_all"]
