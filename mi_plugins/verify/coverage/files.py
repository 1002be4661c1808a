"""Small data files the coverage rows reference (written once into the package's cache):
Wavefront OBJ, Mitsuba's ``serialized`` format, PLY with vertex colours, curve files.

Nothing is downloaded: every file is generated from the meshes of
:mod:`mi_plugins.verify.conformance.meshes`.
"""
import hashlib
import os
import struct
import zlib

import numpy as np

from mi_plugins.verify import geometry


def _cached(name, payload, write):
    digest = hashlib.sha1(payload).hexdigest()[:12]
    path = os.path.join(geometry.cache_dir(), "%s-%s" % (digest, name))
    if not os.path.exists(path):
        tmp = path + ".%d.tmp" % os.getpid()
        write(tmp)
        os.replace(tmp, path)
    return path


def _key(mesh):
    return mesh.vertices.astype("<f4").tobytes() + mesh.faces.astype("<i4").tobytes()


def obj_file(mesh, name):
    """A Wavefront OBJ file of ``mesh`` (positions, uv, triangles)."""
    def write(path):
        with open(path, "w") as f:
            f.writelines("v %.7g %.7g %.7g\n" % tuple(v) for v in mesh.vertices)
            f.writelines("vt %.7g %.7g\n" % tuple(t) for t in mesh.uvs)
            f.writelines("f %d/%d %d/%d %d/%d\n" % tuple(np.repeat(face + 1, 2)) for face in mesh.faces)
    return _cached(name + ".obj", _key(mesh), write)


def serialized_file(mesh, name):
    """A file in Mitsuba's ``serialized`` format (version 4, one single-precision mesh
    with uv coordinates, zlib-compressed, with its offset table)."""
    def write(path):
        flags = 0x0002 | 0x1000                    # texture coordinates, single precision
        body = struct.pack("<I", flags) + name.encode("utf-8") + b"\0"
        body += struct.pack("<QQ", len(mesh.vertices), len(mesh.faces))
        body += mesh.vertices.astype("<f4").tobytes() + mesh.uvs.astype("<f4").tobytes()
        body += mesh.faces.astype("<u4").tobytes()
        with open(path, "wb") as f:
            f.write(struct.pack("<HH", 0x041C, 4))
            f.write(zlib.compress(body))
            f.write(struct.pack("<QI", 0, 1))       # offset of mesh 0, mesh count
    return _cached(name + ".serialized", _key(mesh), write)


def colored_ply_file(mesh, colors, name):
    """A binary PLY of ``mesh`` with per-vertex RGB colours (read by Mitsuba as the
    ``vertex_color`` attribute, for the ``mesh_attribute`` texture)."""
    colors = np.asarray(colors, dtype=np.float64)

    def write(path):
        vertex = np.empty(len(mesh.vertices), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("u", "<f4"),
                                                      ("v", "<f4"), ("r", "<f4"), ("g", "<f4"), ("b", "<f4")])
        vertex["x"], vertex["y"], vertex["z"] = mesh.vertices.T
        vertex["u"], vertex["v"] = mesh.uvs.T
        vertex["r"], vertex["g"], vertex["b"] = colors.T
        face = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        face["n"], face["i"] = 3, mesh.faces
        header = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
                  "property float z\nproperty float u\nproperty float v\nproperty float r\nproperty float g\n"
                  "property float b\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n"
                  % (len(vertex), len(face)))
        with open(path, "wb") as f:
            f.write(header.encode("ascii"))
            f.write(vertex.tobytes())
            f.write(face.tobytes())
    return _cached(name + ".ply", _key(mesh) + colors.astype("<f4").tobytes(), write)


def curve_file(curves, name):
    """A curve file of Mitsuba's ``bsplinecurve``/``linearcurve`` shapes: one control
    point "x y z radius" per line, a blank line between curves."""
    text = "\n\n".join("\n".join("%.7g %.7g %.7g %.7g" % tuple(p) for p in c) for c in curves) + "\n"

    def write(path):
        with open(path, "w") as f:
            f.write(text)
    return _cached(name + ".txt", text.encode("ascii"), write)
