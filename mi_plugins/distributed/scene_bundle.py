"""Scenes shipped to the workers: the XML file and every file it references.

:func:`bundle` reads a scene file, follows its ``<include>`` files and every ``filename``
(meshes, textures, environment maps, spectra: a ``<string name="filename">`` or a
``filename`` attribute), substituting ``$parameters`` from ``params``, and returns a
:class:`SceneBundle`: the files' bytes under their paths relative to a common root, and
a content hash. :func:`materialize` writes a bundle once per worker process into a
temporary directory named by that hash, in the same layout, so relative references
resolve there exactly as on the submitting machine. Files named by an absolute path are
not shipped: they must exist at that path on every worker (a shared filesystem), and
:func:`materialize` says so by name when one does not.
"""
import hashlib
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field


@dataclass
class SceneBundle:
    scene: str                       # the scene file, relative to the root
    files: dict                      # relative path -> bytes
    absolute: list = field(default_factory=list)   # referenced by absolute path: not shipped
    digest: str = ""

    @property
    def size(self):
        return sum(len(b) for b in self.files.values())


def _substitute(value, params):
    return re.sub(r"\$(\w+)", lambda m: str(params.get(m.group(1), m.group(0))), value)


def _references(path, params):
    """(included XML files, other referenced files) of one XML file, as written."""
    root = ET.parse(path).getroot()
    includes, files = [], []
    for el in root.iter():
        if el.tag == "include" and "filename" in el.attrib:
            includes.append(_substitute(el.attrib["filename"], params))
        elif el.attrib.get("name") == "filename" and "value" in el.attrib:
            files.append(_substitute(el.attrib["value"], params))
        elif "filename" in el.attrib:
            files.append(_substitute(el.attrib["filename"], params))
    return includes, files


def bundle(scene_file, params=None):
    """The :class:`SceneBundle` of ``scene_file`` (FileNotFoundError naming a referenced
    file that does not exist)."""
    params = dict(params or {})
    scene_file = os.path.abspath(scene_file)
    found, absolute, todo = {}, [], [scene_file]
    while todo:
        xml = todo.pop()
        if xml in found:
            continue
        found[xml] = True
        base = os.path.dirname(xml)
        includes, files = _references(xml, params)
        for ref, is_xml in [(r, True) for r in includes] + [(r, False) for r in files]:
            if os.path.isabs(ref):
                absolute.append(ref)
                continue
            target = os.path.normpath(os.path.join(base, ref))
            if not os.path.isfile(target):
                raise FileNotFoundError("scene '%s' references '%s' (in %s), which does not exist"
                                        % (scene_file, ref, xml))
            if is_xml:
                todo.append(target)
            else:
                found[target] = True
    root = os.path.commonpath([os.path.dirname(p) for p in found])
    files = {}
    for p in sorted(found):
        with open(p, "rb") as f:
            files[os.path.relpath(p, root)] = f.read()
    h = hashlib.sha1()
    for name, data in sorted(files.items()):
        h.update(name.encode() + b"\0" + hashlib.sha1(data).digest())
    return SceneBundle(os.path.relpath(scene_file, root), files, sorted(set(absolute)), h.hexdigest()[:16])


def materialize(b):
    """Write bundle ``b`` (once per process and digest) and return its scene file's path."""
    root = os.path.join(tempfile.gettempdir(), "mi_plugins_scenes", b.digest)
    done = os.path.join(root, ".complete")
    if not os.path.exists(done):
        for name, data in b.files.items():
            path = os.path.join(root, name)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            tmp = "%s.%d.tmp" % (path, os.getpid())
            with open(tmp, "wb") as f:
                f.write(data)
            os.replace(tmp, path)           # atomic: workers of one machine may race
        open(done, "w").close()
    missing = [p for p in b.absolute if not os.path.exists(p)]
    if missing:
        raise FileNotFoundError("the scene references %s by absolute path, which this worker does not have; "
                                "use paths relative to the scene file (shipped with the tasks) or a filesystem "
                                "shared by all workers" % ", ".join(repr(p) for p in missing))
    return os.path.join(root, b.scene)
