"""Baked lighting as glTF 2.0: a solution's meshes with per-vertex radiance in one file.

Every shape becomes a node with one mesh (``mi_plugins.solution.export.baked_shapes``:
the patches' triangles wound along the patch normals, the smooth field's vertices):

- ``POSITION`` (float), ``NORMAL`` (float: the area-weighted mean of the normals of the
  vertex's triangles, on the side the patch normal points to), indices (unsigned int);
- ``COLOR_0`` (float RGB): the outgoing radiance of side 0 (emission included) divided
  by ``radiance_scale`` and clipped to [0, 1], **linear** (glTF's rule: no sRGB
  encoding; a viewer encodes it for the screen); ``radiance_scale`` is the 99th
  percentile of every side-0 vertex value, as the PLY's display colours;
- ``_RADIANCE`` (float RGB, an application attribute glTF readers keep or ignore): the
  radiance itself, HDR, unscaled and unclipped;
- where side 1 sends light anywhere on the shape, a second primitive with the reversed
  triangles, negated normals and side 1's values.

The one material is unlit (``KHR_materials_unlit``, base colour white, single-sided):
viewers show ``COLOR_0`` as it is. The root's ``extras`` state the encoding, the scale
and the number of clipped vertices; coordinates are the scene's (glTF's +Y up is not
imposed). ``.glb`` writes the binary container, ``.gltf`` JSON with the buffer embedded
as a base64 data URI.
"""
import base64
import json
import os
import struct

import numpy as np

#: the encoding, as the file's extras state it
COLOR_RULE = ("COLOR_0 = clip(radiance / radiance_scale, 0, 1), linear (not sRGB-encoded); "
              "_RADIANCE = radiance (HDR, the units of the scene's emitters)")
_FLOAT, _UINT = 5126, 5125
_ARRAY, _ELEMENTS = 34962, 34963


def vertex_normals(positions, faces):
    """(V, 3) unit normals: the sum of the vertex's triangles' cross products (area-weighted
    face normals along the winding), normalised."""
    p = positions[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normals = np.zeros_like(positions, dtype=np.float64)
    for k in range(3):
        np.add.at(normals, faces[:, k], cross)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.maximum(length, 1e-30)


class _Buffer:
    """The binary buffer and its views and accessors, 4-byte aligned."""

    def __init__(self):
        self.chunks, self.size, self.views, self.accessors = [], 0, [], []

    def add(self, array, kind, target, bounds=False):
        array = np.ascontiguousarray(array, dtype=np.float32 if kind != "SCALAR" else np.uint32)
        data = array.tobytes()
        self.views.append({"buffer": 0, "byteOffset": self.size, "byteLength": len(data), "target": target})
        self.chunks.append(data + b"\0" * (-len(data) % 4))
        self.size += len(data) + (-len(data) % 4)
        accessor = {"bufferView": len(self.views) - 1, "componentType": _UINT if kind == "SCALAR" else _FLOAT,
                    "count": int(array.size if kind == "SCALAR" else len(array)), "type": kind}
        if bounds:
            flat = array.reshape(-1, 1) if kind == "SCALAR" else array
            accessor["min"] = [v.item() for v in flat.min(axis=0)]
            accessor["max"] = [v.item() for v in flat.max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def bytes(self):
        return b"".join(self.chunks)


def gltf_document(solution, what="Solution.to_gltf"):
    """(document dict, binary buffer) of ``solution``'s baked meshes (module docstring)."""
    from mi_plugins.solution.export import baked_shapes, display_scale
    shapes = baked_shapes(solution, what)
    scale = display_scale(solution)
    buf, meshes, clipped = _Buffer(), [], 0
    for name, positions, faces, front, back in shapes:
        if not len(faces):
            continue              # (a shape whose patches are all degenerate: glTF has no empty accessor)
        normals = vertex_normals(positions, faces)
        position = buf.add(positions, "VEC3", _ARRAY, bounds=True)
        primitives = []
        for side, values in enumerate((front, back)):
            if side == 1 and not np.any(values != 0.0):
                continue          # a side that sends no light: the single-sided material culls it
            color = np.clip(values / scale, 0.0, 1.0)
            clipped += int(np.count_nonzero(np.any(values > scale, axis=1)))
            primitives.append({"attributes": {
                "POSITION": position,
                "NORMAL": buf.add(normals if side == 0 else -normals, "VEC3", _ARRAY),
                "COLOR_0": buf.add(color, "VEC3", _ARRAY, bounds=True),
                "_RADIANCE": buf.add(values, "VEC3", _ARRAY)},
                "indices": buf.add(faces if side == 0 else faces[:, ::-1], "SCALAR", _ELEMENTS, bounds=True),
                "material": 0, "mode": 4, "extras": {"side": side}})
        meshes.append({"name": name, "primitives": primitives})
    meta = solution.meta
    doc = {
        "asset": {"version": "2.0", "generator": "mi_plugins (baked lighting of a view-independent solution)"},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0, "scenes": [{"nodes": list(range(len(meshes)))}],
        "nodes": [{"name": m["name"], "mesh": k} for k, m in enumerate(meshes)],
        "meshes": meshes,
        "materials": [{"name": "baked radiance", "doubleSided": False,
                       "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0,
                                                "roughnessFactor": 1.0},
                       "extensions": {"KHR_materials_unlit": {}}}],
        "accessors": buf.accessors, "bufferViews": buf.views,
        "buffers": [{"byteLength": buf.size}],
        "extras": {"mi_plugins": {"color_0": COLOR_RULE, "radiance_scale": scale, "clipped_vertices": clipped,
                                  "integrator": meta.get("integrator"), "seed": meta.get("seed"),
                                  "fingerprint": meta.get("fingerprint")}},
    }
    return doc, buf.bytes()


def write_gltf(solution, path):
    """Write ``solution``'s baked meshes to ``path``: ``.glb`` (binary) or ``.gltf`` (JSON,
    buffer embedded); returns the path."""
    ext = os.path.splitext(str(path))[1].lower()
    if ext not in (".glb", ".gltf"):
        raise ValueError("Solution.to_gltf: path '%s' must end in .glb (binary glTF) or .gltf (JSON with the "
                         "buffer embedded)" % path)
    doc, data = gltf_document(solution)
    folder = os.path.dirname(os.path.abspath(str(path)))
    os.makedirs(folder, exist_ok=True)
    if ext == ".gltf":
        doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(data).decode("ascii")
        with open(path, "w") as f:
            json.dump(doc, f, separators=(",", ":"))
        return path
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(data)
    with open(path, "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, total))
        f.write(struct.pack("<I4s", len(text), b"JSON") + text)
        f.write(struct.pack("<I4s", len(data), b"BIN\0") + data)
    return path
