"""Baked lighting: a solution's meshes with per-vertex radiance, as PLY files.

Every shape of the scene becomes one binary PLY mesh made of its patches (a mesh's
triangles and sub-triangles; two triangles per cell of an analytic shape, across which
the colours are linear where the ``baked`` display interpolates a cell bilinearly),
wound so that its geometric normal is the patch normal (side 0; ``flip_normals``
included), with the vertices the smooth display uses (``mi_plugins.solution.patchfield``) and
their radiance:

- float properties ``r g b``: the outgoing radiance of side 0 (emission included), HDR;
  Mitsuba reads them as the ``vertex_color`` attribute, which the ``mesh_attribute``
  texture interpolates (e.g. as the radiance of an ``area`` emitter: rendered with
  ``path`` at ``max_depth`` 1, the mesh shows its baked lighting);
- float ``back_r back_g back_b`` (Mitsuba: ``vertex_back_color``): side 1, for surfaces
  that reflect on both sides;
- with ``display_colors``, 8-bit ``red green blue``: side 0 in sRGB, scaled so that the
  99th percentile of all vertices is white, for mesh viewers (Mitsuba ignores them,
  with a warning).
"""
import os
import re

import numpy as np

#: corner triples of the two triangles of an analytic cell (corners (u0, v0), (u1, v0), (u0, v1), (u1, v1))
CELL_TRIANGLES = ((0, 1, 3), (0, 3, 2))


def _srgb(linear):
    a = np.clip(linear, 0.0, 1.0)
    return np.where(a <= 0.0031308, 12.92 * a, 1.055 * a ** (1 / 2.4) - 0.055)


def shape_faces(field, elements):
    """(local vertex ids (V_s,), faces (F, 3) into them) of the elements ``elements`` of one
    shape, degenerate triangles left out, each wound along its element's normal."""
    mesh = field.kind[elements] == 0
    cells = elements[~mesh]
    tri = [np.stack([field.vertex_ids[elements[mesh], k] for k in (0, 1, 2)], axis=1),
           np.concatenate([np.stack([field.vertex_ids[cells, k] for k in t], axis=1) for t in CELL_TRIANGLES])
           if len(cells) else np.zeros((0, 3), np.int64)]
    normals = [field.element_normals[elements[mesh]], np.concatenate([field.element_normals[cells]] * 2)
               if len(cells) else np.zeros((0, 3))]
    faces, normal = np.concatenate(tri), np.concatenate(normals)
    p = field.vertex_positions[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = np.linalg.norm(cross, axis=1)
    keep = area > 1e-12 * max(float(area.max(initial=0.0)), 1e-30)
    wrong = np.einsum("ij,ij->i", cross, normal) < 0
    faces = np.where(wrong[:, None], faces[:, ::-1], faces)[keep]
    ids, local = np.unique(faces, return_inverse=True)
    return ids, local.reshape(-1, 3)


def baked_shapes(solution, what="Solution.to_ply"):
    """Every shape of ``solution`` as [(name, positions (V, 3), faces (F, 3), front (V, 3),
    back (V, 3))]: its patches' triangles wound along the patch normals (side 0), the
    vertices of the smooth field and their radiance (side 0, side 1; emission included).
    Names are the shapes' ids made file-safe and unique. ``what``: the caller, for the
    error of an incomplete solution."""
    field = solution.field
    if field is None or solution.radiance is None:
        raise ValueError("%s: this solution is not complete; get it with mi_plugins.solve(scene, ...) "
                         "or Solution.load(path, scene)" % what)
    radiance = solution.vertex_values("radiance")                    # (V, 2, 3)
    bad = int(np.count_nonzero(~np.isfinite(radiance).all(axis=(1, 2))))
    if bad:
        raise ValueError("%s: the solution's radiance is not finite at %d of %d vertices; solve the scene again"
                         % (what, bad, len(radiance)))
    out, used = [], set()
    for k, shape in enumerate(solution.meta["shapes"]):
        ids, faces = shape_faces(field, np.flatnonzero((field.element_shape == k) & field.leaf))
        name = re.sub(r"[^A-Za-z0-9_.-]+", "_", shape["id"] or "shape") or "shape"
        while name in used:
            name += "_%d" % k
        used.add(name)
        out.append((name, field.vertex_positions[ids], faces, radiance[ids, 0], radiance[ids, 1]))
    return out


def display_scale(solution):
    """The radiance shown as white by the 8-bit display colours: the 99th percentile of
    every side-0 vertex value (all channels), at least 1e-12."""
    return max(float(np.percentile(solution.vertex_values("radiance")[:, 0], 99)), 1e-12)


def write_meshes(solution, folder, display_colors=False):
    """Write one PLY per shape of ``solution`` into ``folder``; returns the paths."""
    shapes = baked_shapes(solution)
    os.makedirs(folder, exist_ok=True)
    scale = display_scale(solution) if display_colors else 1.0
    paths = []
    for name, positions, faces, front, back in shapes:
        path = os.path.join(folder, name + ".ply")
        write_ply(path, positions, faces, front, back, _srgb(front / scale) if display_colors else None)
        paths.append(path)
    return paths


def write_ply(path, positions, faces, front, back, display=None):
    """A binary little-endian PLY with float32 positions, front and back radiance, and
    optionally 8-bit display colours."""
    fields = [(c, "<f4") for c in ("x", "y", "z", "r", "g", "b", "back_r", "back_g", "back_b")]
    if display is not None:
        fields += [(c, "u1") for c in ("red", "green", "blue")]
    vertex = np.empty(len(positions), dtype=fields)
    for j, c in enumerate("xyz"):
        vertex[c] = positions[:, j]
    for j, c in enumerate("rgb"):
        vertex[c], vertex["back_" + c] = front[:, j], back[:, j]
    if display is not None:
        for j, c in enumerate(("red", "green", "blue")):
            vertex[c] = np.round(display[:, j] * 255).astype(np.uint8)
    face = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, faces
    header = ["ply", "format binary_little_endian 1.0", "comment baked lighting of mi_plugins",
              "element vertex %d" % len(vertex)]
    header += ["property %s %s" % ("float" if t == "<f4" else "uchar", c) for c, t in fields]
    header += ["element face %d" % len(face), "property list uchar int vertex_indices", "end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(vertex.tobytes())
        f.write(face.tobytes())
    return path
