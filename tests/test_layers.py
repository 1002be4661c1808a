"""The package's layers: imports only run downward and never in a circle.

Every module of the package (``mi_plugins/`` and the plugin folders installed into it) is
read as text; each import, at the top of a file or inside a function, is an arrow from the
importing module to the imported one. The layers, from the bottom: ``base``, ``light``,
``patches``, ``render``, ``solution``, the plugins (``integrators``, ``bsdfs``, ``emitters``,
``samplers``), the package root (``mi_plugins/__init__.py``, ``registry``), ``verify``,
``distributed``, ``app`` and ``__main__``. An arrow to a higher layer fails, and so does a
circle of arrows, within a layer too. The test of the test: a made-up graph with an arrow up
and a circle is reported on both counts.
"""
import ast
import os

from conftest import REPO

#: the layers from the bottom; a module belongs to the first whose prefix it has
LAYERS = (("mi_plugins.base",), ("mi_plugins.light",), ("mi_plugins.patches",), ("mi_plugins.render",),
          ("mi_plugins.solution",),
          ("mi_plugins.integrators", "mi_plugins.bsdfs", "mi_plugins.emitters", "mi_plugins.samplers"),
          ("mi_plugins.registry", "mi_plugins"), ("mi_plugins.verify",), ("mi_plugins.distributed",),
          ("mi_plugins.app",), ("mi_plugins.__main__",))
#: repository folder -> package it installs as
FOLDERS = {"mi_plugins": "mi_plugins", "integrators": "mi_plugins.integrators", "bsdfs": "mi_plugins.bsdfs",
           "emitters": "mi_plugins.emitters", "samplers": "mi_plugins.samplers"}


def layer(module):
    """The index of the layer ``module`` belongs to (the longest matching prefix wins)."""
    best, length = None, -1
    for k, prefixes in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > length:
                best, length = k, len(p)
    return best


def modules():
    """{dotted module name: file path} of the whole package."""
    out = {}
    for folder, package in FOLDERS.items():
        for dp, dirs, files in os.walk(os.path.join(REPO, folder)):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(dp, f), os.path.join(REPO, folder))[:-3].replace(os.sep, ".")
                    name = package + ("" if rel == "__init__" else "." + rel.replace(".__init__", ""))
                    out[name] = os.path.join(dp, f)
    return out


def arrows(found):
    """{module: set of package modules it imports} (top-level and function-level imports)."""
    out = {}
    for name, path in found.items():
        package = name if path.endswith("__init__.py") else name.rsplit(".", 1)[0]
        targets = set()
        for node in ast.walk(ast.parse(open(path).read(), path)):
            if isinstance(node, ast.Import):
                candidates = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")
                    parts = parts[:len(parts) - (node.level - 1)]
                    base = ".".join(parts + ([base] if base else []))
                candidates = [base + "." + a.name for a in node.names] + [base]
            else:
                continue
            for c in candidates:
                while c and c not in found:
                    c = c.rsplit(".", 1)[0] if "." in c else ""
                if c and c != name:
                    targets.add(c)
                    break
        out[name] = targets
    return out


def upward(graph):
    """The arrows (a, b) from a lower layer to a higher one."""
    return sorted((a, b) for a, targets in graph.items() for b in targets if layer(b) > layer(a))


def circles(graph):
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_every_module_is_in_a_layer():
    assert [m for m in modules() if layer(m) is None] == []


def test_imports_run_downward():
    assert upward(arrows(modules())) == []


def test_no_import_circles():
    assert circles(arrows(modules())) == []


def test_the_checks_see_an_arrow_up_and_a_circle():
    graph = {"mi_plugins.base.a": {"mi_plugins.render.core"}, "mi_plugins.render.core": {"mi_plugins.render.x"},
             "mi_plugins.render.x": {"mi_plugins.render.core"}}
    assert upward(graph) == [("mi_plugins.base.a", "mi_plugins.render.core")]
    assert circles(graph) == [["mi_plugins.render.core", "mi_plugins.render.x"]]
    assert layer("mi_plugins.registry") == layer("mi_plugins") > layer("mi_plugins.integrators.ray_bundle.run")
