"""Write Mitsuba scene dicts as Mitsuba 3 XML files (used to produce ``configs/``).

Meshes referenced by ``ply`` shapes are copied next to the XML (``meshes/``) and
in-memory bitmaps are saved as EXR (``textures/``), referenced by relative paths.
"""
import os
import shutil
from xml.sax.saxutils import quoteattr

import mitsuba as mi
import numpy as np

_KIND_BY_KEY = {"bsdf": "bsdf", "emitter": "emitter", "sensor": "sensor", "film": "film", "rfilter": "rfilter",
                "sampler": "sampler", "integrator": "integrator"}
_INTEGER_KEYS = ("sample_count", "max_depth", "width", "height", "iterations", "resolution")
_PLUGIN_KINDS = {
    "shape": ("ply", "obj", "sphere", "cube", "rectangle", "disk", "cylinder", "serialized"),
    "texture": ("bitmap", "checkerboard", "mesh_attribute", "volume"),
}


def _kind(key, value, parent_kind):
    if key in _KIND_BY_KEY:
        return _KIND_BY_KEY[key]
    t = value.get("type")
    for kind, types in _PLUGIN_KINDS.items():
        if t in types:
            return kind
    if parent_kind == "scene":
        return "shape"
    if parent_kind in ("bsdf", "emitter", "texture"):
        return "bsdf" if parent_kind == "bsdf" and t not in ("rgb", "spectrum") else "texture"
    return "texture"


class _Writer:
    def __init__(self, directory):
        self.directory = directory
        self.lines = []
        self.counter = 0

    def _asset(self, sub, name):
        os.makedirs(os.path.join(self.directory, sub), exist_ok=True)
        return os.path.join(sub, name)

    def value(self, key, value, indent):
        pad = "    " * indent
        name = quoteattr(key)
        if isinstance(value, bool):
            self.lines.append('%s<boolean name=%s value="%s"/>' % (pad, name, str(value).lower()))
        elif isinstance(value, int):
            self.lines.append('%s<integer name=%s value="%d"/>' % (pad, name, value))
        elif isinstance(value, float):
            self.lines.append('%s<float name=%s value="%r"/>' % (pad, name, value))
        elif isinstance(value, str) and value.startswith("$") and key in _INTEGER_KEYS:
            self.lines.append('%s<integer name=%s value=%s/>' % (pad, name, quoteattr(value)))
        elif isinstance(value, str):
            self.lines.append('%s<string name=%s value=%s/>' % (pad, name, quoteattr(value)))
        elif isinstance(value, (list, tuple)) and len(value) == 3:
            self.lines.append('%s<point name=%s value="%s"/>' % (pad, name, ", ".join(repr(float(v)) for v in value)))
        elif isinstance(value, mi.ScalarTransform4f) or type(value).__name__.startswith("ScalarAffineTransform4f") \
                or type(value).__name__.startswith("ScalarTransform4f"):
            m = np.array(value.matrix, dtype=np.float64).reshape(4, 4)
            self.lines.append('%s<transform name=%s>' % (pad, name))
            self.lines.append('%s    <matrix value="%s"/>' % (pad, " ".join("%.9g" % v for v in m.ravel())))
            self.lines.append('%s</transform>' % pad)
        elif isinstance(value, mi.Bitmap):
            self.counter += 1
            rel = self._asset("textures", "%s_%d.exr" % (os.path.splitext(self.basename)[0], self.counter))
            value.write(os.path.join(self.directory, rel))
            self.lines.append('%s<string name="filename" value=%s/>' % (pad, quoteattr(rel)))
        elif isinstance(value, dict):
            self.plugin(key, value, indent, "texture")
        else:
            raise TypeError("cannot write %s=%r as XML" % (key, value))

    def plugin(self, key, d, indent, parent_kind):
        pad = "    " * indent
        t = d["type"]
        if t == "ref":
            self.lines.append('%s<ref name=%s id=%s/>' % (pad, quoteattr(key), quoteattr(d["id"])))
            return
        if t == "rgb":
            v = d["value"]
            v = [v] * 3 if isinstance(v, (int, float)) else v
            self.lines.append('%s<rgb name=%s value="%s"/>' % (pad, quoteattr(key), ", ".join(repr(float(x)) for x in v)))
            return
        kind = _kind(key, d, parent_kind)
        attrs = ' type=%s' % quoteattr(t)
        if kind == "shape":
            attrs += ' id=%s' % quoteattr(key)
        elif "id" in d:
            attrs += ' id=%s' % quoteattr(d["id"])
        elif kind == "texture" or (kind in ("bsdf", "emitter") and key not in _KIND_BY_KEY):
            attrs += ' name=%s' % quoteattr(key)
        if t == "ply" and "filename" in d:
            d = dict(d)
            rel = self._asset("meshes", os.path.basename(d["filename"]))
            shutil.copyfile(d["filename"], os.path.join(self.directory, rel))
            d["filename"] = rel
        self.lines.append("%s<%s%s>" % (pad, kind, attrs))
        for k, v in d.items():
            if k == "type" or k == "id":
                continue
            if isinstance(v, dict):
                self.plugin(k, v, indent + 1, kind)
            else:
                self.value(k, v, indent + 1)
        self.lines.append("%s</%s>" % (pad, kind))


def write_scene(scene_dict, path, header_comment="", defaults=None):
    """Write ``scene_dict`` as Mitsuba XML to ``path``; ``defaults``: {name: value} XML
    parameters declared with <default> (use "$name" strings in the dict to refer to them)."""
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    w = _Writer(directory)
    w.basename = os.path.basename(path)
    w.lines.append('<?xml version="1.0" encoding="utf-8"?>')
    if header_comment:
        w.lines.append("<!--\n%s\n-->" % header_comment.replace("--", "- -"))
    w.lines.append('<scene version="3.0.0">')
    for name, value in (defaults or {}).items():
        w.lines.append('    <default name=%s value=%s/>' % (quoteattr(name), quoteattr(str(value))))
    for key, value in scene_dict.items():
        if key == "type":
            continue
        w.plugin(key, value, 1, "scene")
    w.lines.append("</scene>")
    with open(path, "w") as f:
        f.write("\n".join(w.lines) + "\n")
    return path
