"""The one edit-check-undo mechanism of the package's BSDFs and emitters for Mitsuba's
scene parameters (``mi.traverse`` / ``params.update()``).

A plugin (nanobind allows Python plugins a single base class, so these are functions
its methods call) names itself in ``plugin`` and implements ``_exposed()`` ({name: the
JIT value or texture it exposes in ``traverse``}) and ``_apply(p, keys)`` (read the
exposed values back with the plugin's reader ``p`` and recompute what depends on them);
optionally ``_given()`` (the values the reader sees; default: the exposed ones as a user
would give them) and ``_notify()`` (tell dependent plugins after a valid edit). Its
``parameters_changed`` calls :func:`parameters_changed`, which checks an edit exactly as
at load; an invalid edit raises its ``ParameterError`` and is undone (:func:`undo`: the
last valid values restored, and what depends on them recomputed).
"""
from mi_plugins.base.params import ParameterError, Params
from mi_plugins.base.textures import as_given, as_properties, restore, snapshot


def given(plugin):
    """The exposed values of ``plugin`` as a user would give them."""
    return {name: as_given(value) for name, value in plugin._exposed().items()}


def _reader(plugin):
    values = plugin._given() if hasattr(plugin, "_given") else given(plugin)
    return Params(as_properties(plugin.plugin, values), plugin.plugin)


def _notify(plugin):
    if hasattr(plugin, "_notify"):
        plugin._notify()


def keep_valid(plugin):
    """Called when the parameters of ``plugin`` are valid (at load, after an edit)."""
    plugin._valid = snapshot(plugin._exposed())


def parameters_changed(plugin, keys=()):
    try:
        plugin._apply(_reader(plugin), keys)
        _notify(plugin)
    except ParameterError:
        plugin.undo()
        raise
    keep_valid(plugin)


def undo(plugin, notify=True):
    """Back to the last valid values of ``plugin``, and what depends on them."""
    restore(plugin._exposed(), plugin._valid)
    plugin._apply(_reader(plugin), ())
    if notify:
        _notify(plugin)
