"""The documentation of the plugins' parameters: one row per parameter, written once.

A plugin's class docstring holds its prose and examples and a bare ``..
pluginparameters::`` line; :func:`documented` fills that table in from :class:`Row`\\ s:
the plugin's own and the groups shared by several plugins (the patches' parameters, the
displays', the refinement's: each declared next to the code that reads it). The plugin
reference (``docs/reference.md``) and ``help()`` show the filled-in table, and the test
of the reference checks it lists exactly the parameters the plugin reads.
"""
import inspect
from dataclasses import dataclass, replace

DIRECTIVE = ".. pluginparameters::"


@dataclass(frozen=True)
class Row:
    """One parameter: its name, type, default and what it does (its range first)."""
    name: str
    type: str
    default: str
    meaning: str

    def but(self, **changes):
        """This row with some cells changed (a plugin whose default differs)."""
        return replace(self, **changes)


def rows_text(rows, indent=""):
    """The reStructuredText list-table rows of ``rows``."""
    out = []
    for row in rows:
        cells = (row.name, row.type, row.default, row.meaning)
        out.append(indent + " * - " + cells[0])
        out += [indent + "   - " + c for c in cells[1:]]
    return "\n".join(out)


def documented(*groups):
    """Class decorator: the docstring's bare ``.. pluginparameters::`` table filled in with
    the rows of ``groups`` (each a Row or a sequence of Rows), in order."""
    rows = [r for g in groups for r in ([g] if isinstance(g, Row) else g)]
    names = [r.name for r in rows]
    if len(set(names)) != len(names):
        raise ValueError("documented(): a parameter is documented twice: %s"
                         % sorted({n for n in names if names.count(n) > 1}))

    def decorate(cls):
        doc = inspect.cleandoc(cls.__doc__ or "")
        if DIRECTIVE not in doc.splitlines():
            raise ValueError("%s: the docstring has no bare %r line to fill in" % (cls.__name__, DIRECTIVE))
        head, tail = doc.split(DIRECTIVE, 1)
        cls.__doc__ = head + DIRECTIVE + "\n\n" + rows_text(rows) + "\n" + tail
        return cls
    return decorate
