"""Procedural meshes of the interior benchmark scenes (`interiors.py`), in metres, z up.

Every builder returns triangles as a float64 array (T, 3, 3), wound so that the face
normal points into the free space (out of furniture, into the room): Mitsuba's BSDFs and
area lights are one-sided. :func:`ply` writes a group of them as a binary PLY file into a
cache folder under the system temp dir (``MI_PLUGINS_INTERIORS_CACHE`` overrides it),
named by a hash of the parameters that make it, and builds it only when the file is
missing: a million triangles are generated once per machine, not per scene load.
"""
import hashlib
import os
import tempfile

import numpy as np

from mi_plugins.patches import tessellation
from mi_plugins.verify import geometry as geo

#: part of every cache key: raise it when a builder changes its output
VERSION = 1


def cache_dir():
    d = os.environ.get("MI_PLUGINS_INTERIORS_CACHE") or os.path.join(tempfile.gettempdir(), "mi_plugins_interiors")
    os.makedirs(d, exist_ok=True)
    return d


def key_of(params):
    return hashlib.sha1(repr((VERSION, params)).encode()).hexdigest()[:12]


def ply(name, params, build, uv=None):
    """Path of the cached PLY ``name``-KEY.ply (KEY: a hash of ``params``), written from
    ``build()`` (triangles (T, 3, 3)) when missing; ``uv(points (N, 3)) -> (N, 2)`` sets
    the texture coordinates (default: (0,0), (1,0), (0,1) per triangle)."""
    path = os.path.join(cache_dir(), "%s-%s.ply" % (name, key_of(params)))
    if not os.path.exists(path):
        mesh = geo._unshared_triangles(build())
        if uv is not None:
            mesh.uvs = np.asarray(uv(mesh.vertices), dtype=np.float64)
        geo.write_ply(mesh, path)
    return path


def file_digest(path):
    """A hash of a file's contents (memoised per path and modification time)."""
    stamp = (path, os.path.getmtime(path))
    if stamp not in _DIGESTS:
        h = hashlib.sha1()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 22), b""):
                h.update(block)
        _DIGESTS[stamp] = h.hexdigest()[:16]
    return _DIGESTS[stamp]


_DIGESTS = {}


def ply_faces(path):
    """Triangle count of a PLY file written by :func:`ply` (read from its header)."""
    with open(path, "rb") as f:
        head = f.read(512).split(b"end_header")[0].decode("ascii")
    return int(next(line.split()[2] for line in head.splitlines() if line.startswith("element face")))


# ---------------------------------------------------------------------------- primitives
def orient(tris, outward):
    """``tris`` with every triangle flipped whose normal opposes ``outward`` ((T, 3) or (3,))."""
    tris = np.array(tris, dtype=np.float64).reshape(-1, 3, 3)
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    flip = np.einsum("ij,ij->i", n, np.broadcast_to(outward, n.shape)) < 0
    tris[flip] = tris[flip][:, ::-1]
    return tris


def quads(p0, u, v):
    """Parallelograms p0 + [0,1] u + [0,1] v ((Q, 3) each, or (3,)) as 2 triangles each,
    normals along u x v."""
    p0, u, v = (np.atleast_2d(np.asarray(x, dtype=np.float64)) for x in (p0, u, v))
    p0, u, v = np.broadcast_arrays(p0, u, v)
    a, b, c, d = p0, p0 + u, p0 + u + v, p0 + v
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def boxes(lo, hi):
    """Axis-aligned boxes [lo, hi] ((B, 3) each), 12 triangles each, outward."""
    lo, hi = np.atleast_2d(np.asarray(lo, dtype=np.float64)), np.atleast_2d(np.asarray(hi, dtype=np.float64))
    corners = np.stack([np.where(np.array([(i >> k) & 1 for k in range(3)], bool), hi, lo) for i in range(8)], 1)
    faces = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])
    q = corners[:, faces]                                            # (B, 6, 4, 3)
    tris = np.concatenate([q[:, :, [0, 1, 2]], q[:, :, [0, 2, 3]]], axis=1).reshape(-1, 3, 3)
    centre = np.repeat(0.5 * (lo + hi), 12, axis=0)
    return orient(tris, tris.mean(axis=1) - centre)


def lathe(radius, z, centre, segments=32, caps=True):
    """Body of revolution about the vertical line through ``centre`` (x, y, z0): profile
    radii ``radius`` at heights z0 + ``z`` (both (P,)); the end discs where ``caps``."""
    r, z = np.asarray(radius, np.float64), np.asarray(z, np.float64)
    a = np.linspace(0.0, 2 * np.pi, segments + 1)
    ring = np.stack([np.cos(a), np.sin(a)], -1)                      # (S + 1, 2)
    pts = np.concatenate([r[:, None, None] * ring[None], np.broadcast_to(z[:, None, None], (len(z), segments + 1, 1))],
                         -1)                                          # (P, S + 1, 3)
    p00, p01, p10, p11 = pts[:-1, :-1], pts[:-1, 1:], pts[1:, :-1], pts[1:, 1:]
    tris = np.concatenate([np.stack([p00, p01, p11], -2), np.stack([p00, p11, p10], -2)]).reshape(-1, 3, 3)
    if caps:
        for k in (0, -1):
            rim = pts[k]
            mid = np.broadcast_to([0.0, 0.0, z[k]], rim[:-1].shape)
            tris = np.concatenate([tris, np.stack([mid, rim[:-1], rim[1:]], 1)])
    tris = tris[np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1) > 1e-12]
    c = tris.mean(axis=1)
    top, bottom = np.isclose(c[:, 2], z[-1]) & caps, np.isclose(c[:, 2], z[0]) & caps
    out = np.concatenate([c[:, :2], np.zeros((len(c), 1))], 1)
    out[top], out[bottom] = [0, 0, 1], [0, 0, -1]
    return orient(tris, out) + np.asarray(centre, np.float64)


def cylinders(base, radius, height, segments=16):
    """Upright closed cylinders at ``base`` ((C, 3): bottom centres)."""
    one = lathe([radius, radius], [0.0, height], (0, 0, 0), segments)
    return (one[None] + np.atleast_2d(base)[:, None, None]).reshape(-1, 3, 3)


def tube(path, radius, segments=12):
    """A closed tube of ``radius`` along the polyline ``path`` (N, 3), outward."""
    path = np.asarray(path, np.float64)
    t = np.gradient(path, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    ref = np.where(np.abs(t[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    n = np.cross(t, ref)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    b = np.cross(t, n)
    a = np.linspace(0, 2 * np.pi, segments + 1)
    ring = path[:, None] + radius * (np.cos(a)[None, :, None] * n[:, None] + np.sin(a)[None, :, None] * b[:, None])
    p00, p01, p10, p11 = ring[:-1, :-1], ring[:-1, 1:], ring[1:, :-1], ring[1:, 1:]
    tris = np.concatenate([np.stack([p00, p01, p11], -2), np.stack([p00, p11, p10], -2)]).reshape(-1, 3, 3)
    axis = np.repeat(0.5 * (path[:-1] + path[1:]), segments, axis=0)
    return orient(tris, tris.mean(axis=1) - np.concatenate([axis, axis]))


def teapot(centre, size):
    """A teapot of height ``size``: body and lid of revolution, a spout and a handle (tubes)."""
    z = np.linspace(0.0, 1.0, 24)
    r = 0.36 * np.sin(np.pi * (0.12 + 0.8 * z)) + 0.12 * (z < 0.05)
    body = lathe(np.append(r, 0.16), np.append(0.8 * z, 0.86), (0, 0, 0), 40)
    knob = lathe([0.05, 0.07, 0.0], [0.86, 0.92, 0.96], (0, 0, 0), 16, caps=False)
    s = np.linspace(0, 1, 12)[:, None]
    spout = tube(np.concatenate([0.3 + 0.3 * s, 0 * s, 0.3 + 0.4 * s ** 1.5], 1), 0.05, 12)
    a = np.linspace(-0.6 * np.pi, 0.6 * np.pi, 18)[:, None]
    handle = tube(np.concatenate([-0.3 - 0.22 * np.cos(a), 0 * a, 0.45 + 0.22 * np.sin(a)], 1), 0.03, 10)
    return np.concatenate([body, knob, spout, handle]) * size + np.asarray(centre, np.float64)


def scanned(k, radius, centre, seed=0, stretch=(1.0, 1.0, 1.0)):
    """A 'scanned' object: a geodesic sphere of 20 k^2 triangles (icosahedron faces split
    k x k, crack-free: `mi_plugins.patches.tessellation.triangle_lattice`) displaced by a seeded sum
    of waves, scaled by ``stretch``, resting on the plane z = centre[2]."""
    rng = np.random.default_rng(seed)
    ico = geo.icosphere(0, inward=False)
    lattice = tessellation.triangle_lattice(k)
    w = np.concatenate([(k - lattice.sum(-1))[..., None], lattice], axis=-1) / k
    p = np.einsum("tvc,fcx->ftvx", w, ico.vertices[ico.faces]).reshape(-1, 3, 3)
    d = p / np.linalg.norm(p, axis=-1, keepdims=True)
    r = np.ones(d.shape[:2])
    for amp, freq in ((0.10, 3.0), (0.05, 7.0), (0.025, 15.0), (0.012, 31.0)):
        direction = rng.normal(size=3)
        r += amp * np.sin(freq * d @ (direction / np.linalg.norm(direction)) + rng.uniform(0, 2 * np.pi))
    p = d * r[..., None] * radius * np.asarray(stretch, np.float64)
    p += np.asarray(centre, np.float64) - [0.0, 0.0, p[..., 2].min()]
    return p


# ---------------------------------------------------------------------------- walls
def plane_with_openings(origin, u, v, size_u, size_v, openings=()):
    """The rectangle origin + [0, size_u] u + [0, size_v] v (u, v unit vectors) without the
    rectangular ``openings`` [(u0, v0, u1, v1)], as the cells of the grid their edges make;
    normals along u x v."""
    us = np.unique(np.concatenate([[0.0, size_u], np.ravel([(o[0], o[2]) for o in openings] or [0.0])]))
    vs = np.unique(np.concatenate([[0.0, size_v], np.ravel([(o[1], o[3]) for o in openings] or [0.0])]))
    cu, cv = np.meshgrid(0.5 * (us[:-1] + us[1:]), 0.5 * (vs[:-1] + vs[1:]), indexing="ij")
    keep = np.ones(cu.shape, bool)
    for u0, v0, u1, v1 in openings:
        keep &= ~((cu > u0) & (cu < u1) & (cv > v0) & (cv < v1))
    i, j = np.nonzero(keep)
    u, v, origin = (np.asarray(x, np.float64) for x in (u, v, origin))
    p0 = origin + us[i, None] * u + vs[j, None] * v
    return quads(p0, (us[i + 1] - us[i])[:, None] * u, (vs[j + 1] - vs[j])[:, None] * v)


def reveals(origin, u, v, normal, depth, openings):
    """The sides of rectangular ``openings`` [(u0, v0, u1, v1)] through a wall of ``depth``
    (from its face origin + a u + b v along -``normal``), facing into each opening."""
    u, v, n, origin = (np.asarray(x, np.float64) for x in (u, v, normal, origin))
    out = []
    for u0, v0, u1, v1 in openings:
        centre = origin + 0.5 * (u0 + u1) * u + 0.5 * (v0 + v1) * v - 0.5 * depth * n
        for a, e in (((u0, v0), (u1 - u0) * u), ((u0, v1), (u1 - u0) * u), ((u0, v0), (v1 - v0) * v),
                     ((u1, v0), (v1 - v0) * v)):
            q = quads(origin + a[0] * u + a[1] * v, e, -depth * n)
            out.append(orient(q, centre - q.mean(axis=1)))
    return np.concatenate(out) if out else np.zeros((0, 3, 3))
