"""The plugin reference, generated from the plugins' class docstrings.

Every plugin documents itself in its class docstring, in one style (that of Mitsuba's
own Python plugins)::

    .. _integrator-name:

    Title (``name``)
    ----------------

    Text (Markdown-compatible; ``code`` becomes `code`).

    .. pluginparameters::

     * - parameter
       - type
       - default
       - range and meaning (may continue on further indented lines)

    .. code-block:: python

        {'type': 'name', ...}

:func:`markdown` turns the docstrings of all plugins into the plugin reference of
``docs/reference.md`` (between :data:`BEGIN` and :data:`END`); ``python3
docs/generate_reference.py`` writes it and ``--check`` fails when it is stale (a test
runs the check).
"""
import importlib
import inspect
import re

from mi_plugins import registry

BEGIN = "<!-- BEGIN generated plugin reference: python3 docs/generate_reference.py -->"
END = "<!-- END generated plugin reference -->"

#: the order of the plugin kinds in the reference, with their headings
KINDS = (("emitter", "Emitter"), ("bsdf", "BSDF"), ("sampler", "Sampler"), ("integrator", "Integrator"))

_ROW = re.compile(r"^\s*\* - (.*)$")
_CELL = re.compile(r"^\s*- (.*)$")


def plugin_classes():
    """``[(kind, name, class)]`` of every plugin, in reference order."""
    table = registry.plugin_table()
    out = []
    for kind, _ in KINDS:
        for name, target in table[kind].items():
            module, cls = target.split(":")
            out.append((kind, name, getattr(importlib.import_module(module), cls)))
    return out


def parameter_rows(doc):
    """The rows ``(name, type, default, meaning)`` of a docstring's pluginparameters table."""
    lines = inspect.cleandoc(doc).splitlines()
    try:
        start = lines.index(".. pluginparameters::")
    except ValueError:
        return []
    rows = []
    for line in lines[start + 1:]:
        if not line.strip():
            continue
        if not line.startswith(" "):
            break
        row, cell = _ROW.match(line), _CELL.match(line)
        if row:
            rows.append([row.group(1).strip()])
        elif cell:
            rows[-1].append(cell.group(1).strip())
        else:
            rows[-1][-1] += " " + line.strip()
    for row in rows:
        if len(row) != 4:
            raise ValueError("pluginparameters row %r: expected 4 cells (name, type, default, meaning)" % row)
    return [tuple(_inline(c) for c in row) for row in rows]


def _inline(text):
    return re.sub(r"``([^`]+)``", r"`\1`", text)


def _section(kind_title, doc):
    lines = inspect.cleandoc(doc).splitlines()
    out, i = [], 0
    while i < len(lines):
        line = lines[i]
        if line.startswith(".. _"):
            i += 1
        elif i + 1 < len(lines) and lines[i + 1].strip() and set(lines[i + 1].strip()) == {"-"} and line.strip():
            out.append("### %s %s" % (kind_title, _inline(line.strip())))
            i += 2
        elif line.strip() == ".. pluginparameters::":
            out += ["| parameter | type | default | range / meaning |", "|---|---|---|---|"]
            out += ["| `%s` | %s | %s | %s |" % row for row in parameter_rows(doc)]
            i += 1
            while i < len(lines) and (not lines[i].strip() or lines[i].startswith(" ")):
                i += 1
            out.append("")
        elif line.startswith(".. code-block::"):
            out.append("```" + line.split("::")[1].strip())
            i += 1
            block = []
            while i < len(lines) and (not lines[i].strip() or lines[i].startswith(" ")):
                block.append(lines[i])
                i += 1
            while block and not block[-1].strip():
                block.pop()
            out += inspect.cleandoc("\n".join(block)).splitlines() if block else []
            out += ["```", ""]
        else:
            out.append(_inline(line))
            i += 1
    return "\n".join(out).strip("\n")


def markdown():
    """The plugin reference (Markdown) of every plugin, in reference order."""
    titles = dict(KINDS)
    return "\n\n".join(_section(titles[kind], cls.__doc__ or "") for kind, _, cls in plugin_classes()) + "\n"


def readme_block(readme_text):
    """The generated part of ``readme_text`` (between the markers), or None."""
    if BEGIN not in readme_text or END not in readme_text:
        return None
    return readme_text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n") + "\n"


def update_readme(readme_text):
    """``readme_text`` with the generated part replaced by the current reference."""
    head, rest = readme_text.split(BEGIN, 1)
    tail = rest.split(END, 1)[1]
    return head + BEGIN + "\n\n" + markdown() + "\n" + END + tail
