"""Scenes shipped to the workers: the XML file and every file it references.

:func:`bundle` reads a scene file as Mitsuba's parser does: its ``<include>`` files,
``<path>`` entries, ``<default>`` and ``$parameters`` (from ``params``), and every file
named by a ``filename`` (meshes, textures, environment maps: ``<string name="filename">``;
spectra: ``<spectrum filename="...">``). It finds each file where Mitsuba 3 finds it and
returns a :class:`SceneBundle`: the files' bytes under their paths relative to a common
root, the folders ``<path>`` entries name, and a content hash.

Where Mitsuba looks (measured with ``mi.load_file``, Mitsuba 3.9.1). Each relative name is
tried in the folders of a search list in order; the first that exists wins, and a name
found in none is tried from the working directory. Absolute names are used as they are.

* The main file searches its folder, then Mitsuba's global list (the working directory
  at import, Mitsuba's installation folder). A ``<path>`` puts its folder first, for the
  rest of that file's parse and, in the main file, for every object of the scene.
* ``<string name="filename">`` (meshes, textures, ...) is resolved when the scene is
  built, after parsing: with the main file's final list, whichever file it is written in
  and wherever the ``<path>`` stands in the main file. A fragment's own folder and its
  ``<path>`` entries are not searched for it.
* ``<include>`` searches the including file's folder, then that file's current list. The
  included file parses with this list as its own (so a nested include also finds files
  in the folders of the files that include it, innermost first); its ``<path>`` entries
  end with it.
* ``<spectrum filename>`` is resolved at once with the current file's list (for a
  fragment: its ``<path>`` entries and the including file's folder, not its own folder).
* A relative ``<path>`` is the declaring file's folder joined with the value if that
  exists, else the value resolved with the file's current list; a missing one fails.
* ``$name`` in any attribute is replaced by the parameter or an earlier ``<default>``
  (anywhere, includes too), longest names first, as a substring; ``\\$`` escapes it.

The layout: files keep their positions relative to a common root (which includes any
folder outside the main one that a ``<path>`` or ``..`` reaches), and :func:`materialize`
writes them once per machine into a temporary directory named by the hash (each file
whole or not at all, then a completion marker: safe when the tasks and workers of a
machine write it at once), creating the ``<path>`` folders even where nothing is
shipped in them. Mitsuba on the worker reads the unchanged XML, so every search list
names the same folders in the same order; those hold only the shipped files, so no
earlier folder can match instead, and every name resolves to the same file. A file
named by an absolute path, or found through an absolute ``<path>``, is not shipped: it
must exist at that path on every worker (a shared filesystem), and :func:`materialize`
says so by name when it does not (absolute ``<path>`` folders included). A file Mitsuba
finds only through the working directory or its installation folder would not be found
on a worker: :func:`bundle` refuses it by name.
"""
import contextlib
import hashlib
import os
import tempfile
import uuid
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

SHIPPED, SHARED, LOCAL = "shipped", "shared", "local"   # in the bundle; absolute path; this machine only
MAX_INCLUDE_DEPTH = 15                                   # Mitsuba's ParserConfig default
COMPLETE = ".complete"                                   # a bundle's marker: every file written


@dataclass
class SceneBundle:
    scene: str                       # the scene file, relative to the root
    files: dict                      # relative path -> bytes
    absolute: list = field(default_factory=list)   # referenced by absolute path: not shipped
    digest: str = ""
    folders: list = field(default_factory=list)    # <path> folders, relative to the root

    @property
    def size(self):
        return sum(len(b) for b in self.files.values())


def _resolve(name, search):
    """(path, kind) where Mitsuba finds the relative ``name`` in ``search`` (a list of
    (folder, kind)), else from the working directory; None if nowhere."""
    for folder, kind in search:
        path = os.path.normpath(os.path.join(folder, name))
        if os.path.exists(path):
            return path, kind
    return (os.path.abspath(name), LOCAL) if os.path.exists(name) else None


def _folders(search):
    seen = []
    for folder in [f for f, _ in search] + [os.getcwd()]:
        if folder not in seen:
            seen.append(folder)
    return ", ".join(seen)


class _Scene:
    """One walk through a scene's files in document order, as Mitsuba parses them."""

    def __init__(self, scene_file, params):
        import mitsuba as mi
        self.scene_file = scene_file
        self.params = sorted(params.items(), key=lambda kv: -len(kv[0]))
        self.shipped, self.absolute, self.folders, self.late = set(), set(), set(), []
        resolver = mi.file_resolver()
        self.search = [(os.path.dirname(scene_file), SHIPPED)] + \
                      [(os.path.abspath(str(resolver[i])), LOCAL) for i in range(len(resolver))]
        self.parse(scene_file, SHIPPED, self.search, 0)
        for name, written, xml in self.late:            # built after parsing: the main file's list
            self.take(self.find(name, written, xml, self.search))

    def substitute(self, value, xml):
        for key, new in self.params:
            pos = value.find("$" + key)
            while pos >= 0:
                if pos > 0 and value[pos - 1] == "\\":
                    pos = value.find("$" + key, pos + len(key) + 1)
                else:
                    value = value[:pos] + new + value[pos + len(key) + 1:]
                    pos = value.find("$" + key, pos + len(new))
        for pos in (i for i, c in enumerate(value) if c == "$"):
            if pos == 0 or value[pos - 1] != "\\":
                raise ValueError("scene '%s': %s uses an undefined parameter in '%s'" % (self.scene_file, xml, value))
        return value.replace("\\$", "$")

    def find(self, name, written, xml, search, folder=False):
        """(path, kind) of the file (or ``folder``) Mitsuba takes for ``name``."""
        if os.path.isabs(name):
            return name, SHARED
        hit = _resolve(name, search)
        shown = repr(name) if name == written else "%r (written %r)" % (name, written)
        if hit is None:
            raise FileNotFoundError("scene '%s' references %s (in %s), which does not exist in any folder Mitsuba "
                                    "searches for it: %s" % (self.scene_file, shown, xml, _folders(search)))
        if not folder and os.path.isdir(hit[0]):
            raise FileNotFoundError("scene '%s' references %s (in %s), which Mitsuba resolves to the folder '%s'"
                                    % (self.scene_file, shown, xml, hit[0]))
        if hit[1] == LOCAL:
            raise FileNotFoundError("scene '%s' references %s (in %s), which Mitsuba finds only as '%s', through the "
                                    "working directory or Mitsuba's installation folder, which the workers do not "
                                    "share; place it in a folder of the scene or name it with a <path>"
                                    % (self.scene_file, shown, xml, hit[0]))
        return hit

    def take(self, hit):
        (self.shipped if hit[1] == SHIPPED else self.absolute).add(hit[0])

    def parse(self, xml, kind, search, depth):
        """Walk ``xml`` (found as ``kind``) with its search list ``search``, which its
        ``<path>`` entries extend in place."""
        if depth >= MAX_INCLUDE_DEPTH:
            raise ValueError("scene '%s': includes nested deeper than %d at %s" % (self.scene_file, depth, xml))
        self.take((xml, kind))
        here = (os.path.dirname(xml), kind)
        for el in ET.parse(xml).getroot().iter():
            raw = dict(el.attrib)
            attrs = {k: self.substitute(v, xml) if "$" in v else v for k, v in raw.items()}
            if el.tag == "default" and "name" in attrs and attrs["name"] not in dict(self.params):
                self.params.append((attrs["name"], attrs.get("value", "")))
                self.params.sort(key=lambda kv: -len(kv[0]))
            elif el.tag == "path" and "value" in attrs:
                hit = self.find(attrs["value"], raw["value"], xml, [here] + search, folder=True)
                (self.folders if hit[1] == SHIPPED else self.absolute).add(hit[0])
                search.insert(0, hit)
            elif el.tag == "include" and "filename" in attrs:
                inner = [here] + search
                hit = self.find(attrs["filename"], raw["filename"], xml, inner)
                self.parse(hit[0], hit[1], inner, depth + 1)
            elif "filename" in attrs:           # <spectrum filename=...>: read while parsing
                self.take(self.find(attrs["filename"], raw["filename"], xml, search))
            elif el.tag == "string" and attrs.get("name") == "filename" and "value" in attrs:
                self.late.append((attrs["value"], raw["value"], xml))


def bundle(scene_file, params=None):
    """The :class:`SceneBundle` of ``scene_file`` with the ``$parameters`` ``params``
    (FileNotFoundError naming a referenced file Mitsuba would not find, the file that
    references it and the folders searched, or one the workers would not find)."""
    scene_file = os.path.abspath(scene_file)
    walk = _Scene(scene_file, {k: str(v) for k, v in (params or {}).items()})
    root = os.path.commonpath([os.path.dirname(p) for p in walk.shipped] + sorted(walk.folders))
    files = {}
    for p in sorted(walk.shipped):
        with open(p, "rb") as f:
            files[os.path.relpath(p, root)] = f.read()
    folders = sorted(os.path.relpath(d, root) for d in walk.folders)
    h = hashlib.sha1()
    for name, data in sorted(files.items()):
        h.update(name.encode() + b"\0" + hashlib.sha1(data).digest())
    for d in folders:
        h.update(b"folder\0" + d.encode())
    return SceneBundle(os.path.relpath(scene_file, root), files, sorted(walk.absolute), h.hexdigest()[:16], folders)


def _write(path, data):
    """``data`` at ``path``, whole or not at all: written under a name of its own (unique
    across the threads and processes of the machine; permissions as the umask makes
    them), then renamed over ``path``."""
    folder, name = os.path.split(path)
    os.makedirs(folder, exist_ok=True)
    tmp = os.path.join(folder, ".%s.%d.%s.tmp" % (name, os.getpid(), uuid.uuid4().hex))
    try:
        with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise


def _complete(root, b):
    """Bundle ``b`` is whole under ``root``: its marker and every file at its size."""
    try:
        return os.path.exists(os.path.join(root, COMPLETE)) and all(
            os.path.getsize(os.path.join(root, name)) == len(data) for name, data in b.files.items()) and all(
            os.path.isdir(os.path.join(root, d)) for d in b.folders)
    except OSError:
        return False


def materialize(b):
    """Write bundle ``b`` (once per machine and digest) and return its scene file's path.
    Safe when threads and processes of one machine write the same bundle at once: each
    file appears whole (:func:`_write`), and the bundle's marker only after every file,
    so a caller that finds the marker finds every file; one that does not writes them
    all again (the same bytes)."""
    root = os.path.join(tempfile.gettempdir(), "mi_plugins_scenes", b.digest)
    if not _complete(root, b):
        for d in b.folders:
            os.makedirs(os.path.join(root, d), exist_ok=True)
        for name, data in b.files.items():
            _write(os.path.join(root, name), data)
        _write(os.path.join(root, COMPLETE), b"")
    missing = [p for p in b.absolute if not os.path.exists(p)]
    if missing:
        raise FileNotFoundError("the scene references %s by absolute path, which this worker does not have; "
                                "use paths relative to the scene file (shipped with the tasks) or a filesystem "
                                "shared by all workers" % ", ".join(repr(p) for p in missing))
    return os.path.join(root, b.scene)
