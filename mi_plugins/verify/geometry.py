"""Procedural closed geometry for the analytic test scenes.

Every generator returns a :class:`TriangleMesh` (numpy arrays, flat face
normals, per-face texture coordinates); :func:`mesh_file` writes it once as a
binary PLY file into a cache folder so that Mitsuba scene dicts and XML files can
reference it with ``{'type': 'ply', 'filename': ..., 'face_normals': True}``.

Orientation convention: the normals of every surface point into the free space
the camera lives in (inward for enclosures, outward for objects inside them),
because Mitsuba's BSDFs and area emitters are one-sided.
"""
import hashlib
import os
import tempfile
from dataclasses import dataclass

import numpy as np

GEOMETRIES = ("sphere", "sphere_mesh", "box", "sierpinski")


@dataclass
class TriangleMesh:
    vertices: np.ndarray   # (V, 3) float
    faces: np.ndarray      # (F, 3) int, counter-clockwise seen from the side the normal points to
    uvs: np.ndarray        # (V, 2) float

    @property
    def face_count(self):
        return len(self.faces)

    def face_normals(self):
        p0, p1, p2 = (self.vertices[self.faces[:, k]] for k in range(3))
        n = np.cross(p1 - p0, p2 - p0)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def face_areas(self):
        p0, p1, p2 = (self.vertices[self.faces[:, k]] for k in range(3))
        return 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)

    def subset(self, face_mask):
        """The triangles selected by a boolean mask (vertices are kept as they are)."""
        return TriangleMesh(self.vertices, self.faces[np.asarray(face_mask, dtype=bool)], self.uvs)

    def flipped(self):
        return TriangleMesh(self.vertices, self.faces[:, ::-1].copy(), self.uvs)

    @staticmethod
    def concatenate(meshes):
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return TriangleMesh(np.concatenate([m.vertices for m in meshes]),
                            np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]),
                            np.concatenate([m.uvs for m in meshes]))


def _unshared_triangles(tri_vertices):
    """Mesh with 3 own vertices per triangle (flat shading, uv (0,0),(1,0),(0,1))."""
    tri_vertices = np.asarray(tri_vertices, dtype=np.float64).reshape(-1, 3, 3)
    f = len(tri_vertices)
    uvs = np.tile(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), (f, 1))
    return TriangleMesh(tri_vertices.reshape(-1, 3), np.arange(3 * f).reshape(f, 3), uvs)


def box(half_size=1.0):
    """Closed axis-aligned cube [-h, h]^3 with inward normals: 6 faces, 12 triangles.

    Each face has its own 4 vertices with uv covering [0, 1]^2.
    """
    h = float(half_size)
    verts, faces, uvs = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            # inward normal n = -sign * e_axis; (t, b) chosen so that t x b = n
            n = np.zeros(3); n[axis] = -sign
            t = np.zeros(3); t[(axis + 1) % 3] = 1.0
            b = np.cross(n, t)
            c = -n * h
            base = len(verts)
            for (u, v) in ((0, 0), (1, 0), (1, 1), (0, 1)):
                verts.append(c + (2 * u - 1) * h * t + (2 * v - 1) * h * b)
                uvs.append((u, v))
            faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return TriangleMesh(np.array(verts), np.array(faces), np.array(uvs, dtype=np.float64))


def icosphere(subdivisions=2, radius=1.0, inward=True):
    """Geodesic sphere mesh (20 * 4^s triangles) with vertices on the sphere."""
    t = (1.0 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t),
         (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = np.array(v, dtype=np.float64)
    verts /= np.linalg.norm(verts, axis=1, keepdims=True)
    faces = np.array(f, dtype=np.int64)
    for _ in range(int(subdivisions)):
        edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = verts[unique[:, 0]] + verts[unique[:, 1]]
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = inverse.reshape(3, -1).T + len(verts)  # midpoints of edges 01, 12, 20
        verts = np.concatenate([verts, mid])
        a, b, c = faces.T
        m01, m12, m20 = m.T
        faces = np.concatenate([np.stack(s, axis=1) for s in
                                ((a, m01, m20), (b, m12, m01), (c, m20, m12), (m01, m12, m20))])
    mesh = _unshared_triangles(verts[faces] * radius)  # outward-facing, flat shaded
    return mesh.flipped() if inward else mesh


def sierpinski_tetrahedron(level=2, size=1.2, center=(0.0, -0.15, 0.0)):
    """Sierpinski tetrahedron of the given level: 4^level solid tetrahedra with
    outward normals (4^(level+1) triangles). ``size`` is the edge length."""
    s = size / (2 * 2 ** 0.5)
    corners = np.array([(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)], dtype=np.float64) * s
    corners += np.asarray(center, dtype=np.float64)
    tets = corners[None]
    for _ in range(int(level)):
        tets = np.concatenate([(tets + tets[:, k:k + 1]) / 2 for k in range(4)])
    tris = []
    for skip in range(4):  # face opposite corner `skip`, oriented away from it
        idx = [k for k in range(4) if k != skip]
        a, b, c = (tets[:, k] for k in idx)
        n = np.cross(b - a, c - a)
        outward = np.einsum("ij,ij->i", n, a - tets[:, skip]) > 0
        tris.append(np.where(outward[:, None, None], np.stack([a, b, c], 1), np.stack([a, c, b], 1)))
    return _unshared_triangles(np.concatenate(tris))


def write_ply(mesh, path):
    """Write a binary little-endian PLY with positions, uv and triangle faces."""
    vertex = np.empty(len(mesh.vertices), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                                  ("u", "<f4"), ("v", "<f4")])
    vertex["x"], vertex["y"], vertex["z"] = mesh.vertices.T
    vertex["u"], vertex["v"] = mesh.uvs.T
    face = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, mesh.faces
    header = ("ply\nformat binary_little_endian 1.0\ncomment generated by mi_plugins.verify.geometry\n"
              "element vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
              "property float u\nproperty float v\nelement face %d\n"
              "property list uchar int vertex_indices\nend_header\n" % (len(vertex), len(face)))
    tmp = path + ".%d.tmp" % os.getpid()
    with open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vertex.tobytes())
        f.write(face.tobytes())
    os.replace(tmp, path)  # atomic: parallel test workers never see half a file
    return path


def cache_dir():
    d = os.environ.get("MI_PLUGINS_CACHE") or os.path.join(tempfile.gettempdir(), "mi_plugins_meshes")
    os.makedirs(d, exist_ok=True)
    return d


def mesh_file(mesh, name):
    """Path of a cached PLY file holding ``mesh`` (content-addressed)."""
    digest = hashlib.sha1(mesh.vertices.astype("<f4").tobytes() + mesh.faces.astype("<i4").tobytes()
                          + mesh.uvs.astype("<f4").tobytes()).hexdigest()[:12]
    path = os.path.join(cache_dir(), "%s-%s.ply" % (name, digest))
    if not os.path.exists(path):
        write_ply(mesh, path)
    return path


def mesh_shape(mesh, name):
    """A Mitsuba shape dict (without BSDF/emitter) for a TriangleMesh."""
    return {"type": "ply", "filename": mesh_file(mesh, name), "face_normals": True}


def _meshes(geometry, sphere_subdivisions, sierpinski_level):
    """{surface name: (TriangleMesh, cache name, triangles per pattern cell)} of a mesh geometry."""
    if geometry == "sphere_mesh":
        return {"sphere": (icosphere(sphere_subdivisions), "icosphere%d" % sphere_subdivisions, 1)}
    if geometry == "box":
        return {"walls": (box(), "box", 2)}
    if geometry == "sierpinski":
        if int(sierpinski_level) < 0 or int(sierpinski_level) > 6:
            raise ValueError("sierpinski_level=%r: must be an integer in [0, 6]" % (sierpinski_level,))
        return {"walls": (box(), "box", 2),
                "sierpinski": (sierpinski_tetrahedron(sierpinski_level), "sierpinski%d" % sierpinski_level, 1)}
    raise ValueError("geometry=%r: must be one of %s" % (geometry, ", ".join(GEOMETRIES)))


def surfaces(geometry, sphere_subdivisions=3, sierpinski_level=2, pattern=False):
    """Shape dicts (no BSDF/emitter yet) of a closed geometry, keyed by surface name.

    ``'sphere'``: Mitsuba's analytic unit sphere seen from inside (flip_normals);
    ``'sphere_mesh'``: geodesic unit sphere mesh; ``'box'``: the cube [-1, 1]^3;
    ``'sierpinski'``: the box plus a Sierpinski tetrahedron of ``sierpinski_level``.

    With ``pattern=True`` every mesh surface is split into two shapes ``NAME_0`` and
    ``NAME_1`` holding alternating cells (box faces, triangles), so that materials can
    vary over the surface with exactly piecewise-constant values. The analytic sphere
    cannot be split (use a texture there).
    """
    if geometry == "sphere":
        return {"sphere": {"type": "sphere", "radius": 1.0, "flip_normals": True}}
    result = {}
    for name, (mesh, cache_name, cell) in _meshes(geometry, sphere_subdivisions, sierpinski_level).items():
        if not pattern:
            result[name] = mesh_shape(mesh, cache_name)
            continue
        parity = (np.arange(mesh.face_count) // cell) % 2
        for group in (0, 1):
            result["%s_%d" % (name, group)] = mesh_shape(mesh.subset(parity == group),
                                                         "%s_%d" % (cache_name, group))
    return result
