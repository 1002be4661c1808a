"""A disk cache of a scene's setup: what a finite-element integrator builds before its
first light path (each shape's patches and clusters, the dark splits, the gap mouths, the
smooth display's field), so that a later render of the same scene, in this process or
another, does not pay it again.

Entries are keyed by content, never by object identity or file name: the ordered digests
of the scene's shapes and its shapeless emitters (:mod:`mi_plugins.base.fingerprint`), the
settings that shaped the value, and a digest of the package's own code and of the Mitsuba
and Dr.Jit versions, so an edited scene, other settings or an upgraded package build
afresh. Values are numpy arrays in ``.npz`` files (no pickle), written under a temporary
name and renamed, so concurrent processes never read half a file; an unreadable entry is
built again.

Where: ``$MI_PLUGINS_SETUP_CACHE`` (a directory; ``off`` disables the cache), else
``$XDG_CACHE_HOME/mi_plugins/setup`` or ``~/.cache/mi_plugins/setup``. The folder may be
deleted at any time (:func:`clear`)."""
import functools
import hashlib
import os
import shutil
import tempfile

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import fingerprint

ENV = "MI_PLUGINS_SETUP_CACHE"


#: values of ``$MI_PLUGINS_SETUP_CACHE`` that look like a switch, refused rather than
#: taken as a folder of that name in the working directory
_SWITCHES = ("0", "1", "false", "true", "no", "yes", "none", "disable", "disabled", "on")


def directory():
    """The cache folder, or None where ``$MI_PLUGINS_SETUP_CACHE`` is ``off``."""
    chosen = os.environ.get(ENV, "").strip()
    if chosen.lower() == "off":
        return None
    if chosen.lower() in _SWITCHES:
        raise ValueError("$%s=%r: expected a folder for the setup cache, or 'off' to turn it off" % (ENV, chosen))
    if chosen:
        return chosen
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "mi_plugins", "setup")


def clear():
    """Delete every entry."""
    folder = directory()
    if folder and os.path.isdir(folder):
        shutil.rmtree(folder, ignore_errors=True)


@functools.lru_cache(maxsize=1)
def code_digest():
    """Digest of the package's Python sources and the Mitsuba / Dr.Jit versions: a change
    to either makes every earlier entry unreachable."""
    h = hashlib.sha1(("%s %s" % (mi.__version__, dr.__version__)).encode())
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for folder, dirs, files in sorted(os.walk(root)):
        dirs.sort()
        for name in sorted(files):
            if name.endswith(".py"):
                with open(os.path.join(folder, name), "rb") as f:
                    h.update(name.encode())
                    h.update(f.read())
    return h.hexdigest()


def scene_key(scene):
    """The content of ``scene``, whatever the order of its shapes (Mitsuba loads a scene's
    shapes in a different order from one load to the next): entries of a table store the
    order they were made in (:class:`ShapeOrder`)."""
    return fingerprint.scene_fingerprint(scene)


class ShapeOrder:
    """How the patches, elements and shapes of a stored entry map to those of ``table``,
    whose scene holds the same shapes perhaps in another order: the patch table numbers
    patches and elements shape after shape, so a permutation of the shapes is a
    permutation of blocks. ``stored``: the entry's shape digests, in its order."""

    def __init__(self, table, stored):
        digests = fingerprint.shape_digests(table.scene)
        free = {}
        for index, digest in enumerate(digests):
            free.setdefault(digest, []).append(index)
        self.shape = np.array([free[str(d)].pop(0) for d in stored], dtype=np.int64)   # stored k -> here
        self.identity = bool(np.array_equal(self.shape, np.arange(len(digests))))
        counts = np.diff(np.append(table.face_offsets.astype(np.int64), table.front_count))
        self.patch = block_index(table.face_offsets.astype(np.int64), counts, self.shape)
        sizes = np.diff(np.append(table.element_offsets, table.element_count))
        self.element = block_index(table.element_offsets, sizes, self.shape)
        self.patch_of_stored = np.argsort(self.patch)       # stored patch -> here

    def patches(self, values):
        """Stored front patch numbers ``values`` as numbers here."""
        return self.patch_of_stored[np.asarray(values, np.int64)]


DIGESTS = "shape digests"


def block_index(offsets, counts, order):
    """Index (here -> stored) of items numbered in blocks per shape: ``counts`` items of
    shape s starting at ``offsets[s]`` here, stored shape after shape in the order whose
    k-th shape is shape ``order[k]`` here."""
    order = np.asarray(order, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts[order])[:-1]]).astype(np.int64)
    index = np.zeros(int(np.sum(counts)), np.int64)
    for k, here in enumerate(order):          # (a loop over shapes, not patches)
        index[offsets[here]:offsets[here] + counts[here]] = starts[k] + np.arange(counts[here])
    return index


def digests_of(table):
    """The entry record of ``table``'s shape order."""
    return np.array(fingerprint.shape_digests(table.scene))


def token(arrays):
    """A digest of an entry's arrays (what a value derived from it is keyed by)."""
    h = hashlib.sha1()
    for name in sorted(arrays):
        h.update(name.encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def cached_for_table(table, entry, make, to_arrays, from_arrays):
    """:func:`cached` for a value numbered by ``table``'s patches and elements: stored with
    the table's shape order, given back through ``from_arrays(arrays, order)`` with the
    :class:`ShapeOrder` that renumbers it (None: the same order)."""
    def back(arrays):
        order = ShapeOrder(table, arrays.pop(DIGESTS))
        return from_arrays(arrays, None if order.identity else order)
    return cached(entry, make, lambda value: dict(to_arrays(value), **{DIGESTS: digests_of(table)}), back)


def key(*parts):
    """An entry's key from its parts (strings, numbers, tuples: their repr)."""
    return hashlib.sha1(repr((code_digest(),) + parts).encode()).hexdigest()


def _path(entry):
    folder = directory()
    return None if folder is None else os.path.join(folder, entry[:2], entry + ".npz")


def load(entry):
    """{name: numpy array} stored under ``entry``, or None."""
    path = _path(entry)
    if path is None or not os.path.exists(path):
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {name: data[name] for name in data.files}
    except (OSError, ValueError, EOFError):       # (a damaged entry: build again)
        return None


def store(entry, arrays):
    """Store ``arrays`` ({name: numpy array}) under ``entry``; a folder that cannot be
    written leaves the cache empty (the render does not fail for it)."""
    path = _path(entry)
    if path is None:
        return
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
    except OSError:
        pass


def cached(entry, make, to_arrays, from_arrays):
    """The value stored under ``entry`` (``from_arrays``), or ``make()`` stored with
    ``to_arrays``."""
    arrays = load(entry)
    if arrays is not None:
        try:
            return from_arrays(arrays)
        except (KeyError, IndexError, ValueError):          # (an entry of another layout or scene)
            pass
    value = make()
    store(entry, to_arrays(value))
    return value


def pack(fields):
    """{name: array} of a dict whose values are arrays, numbers or tuples of arrays."""
    out = {}
    for name, value in fields.items():
        if isinstance(value, tuple):
            out["%s@%d" % (name, len(value))] = np.zeros(0)
            for i, item in enumerate(value):
                out["%s@%d" % (name, i)] = np.asarray(item)
        else:
            out[name] = np.asarray(value)
    return out


def unpack(arrays):
    """The inverse of :func:`pack` (numbers come back as numpy scalars' Python values)."""
    out, tuples = {}, {}
    for name, value in arrays.items():
        if "@" in name:
            base, index = name.rsplit("@", 1)
            tuples.setdefault(base, {})[int(index)] = value
        else:
            out[name] = value.item() if value.ndim == 0 else value
    for base, items in tuples.items():
        size = max(items)                          # (the marker's index is the length)
        out[base] = tuple(items[i] for i in range(size))
    return out
