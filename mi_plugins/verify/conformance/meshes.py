"""Triangle meshes of the conformance scenes, built in Python.

Every builder returns a :class:`mi_plugins.verify.geometry.TriangleMesh` (numpy arrays);
:func:`shape` turns one into an ordinary Mitsuba ``ply`` shape dict (the PLY file is
written once into the package's mesh cache, content-addressed, by
:func:`mi_plugins.verify.geometry.mesh_file`). Quads are split into ``n x n`` cells of two
triangles each, so that finite-element methods see walls made of many patches, as
in real scenes.

Winding: a quad built from ``(center, u, v)`` has the geometric normal
``u x v`` (counter-clockwise seen from that side). :func:`room` makes a closed box whose
winding faces *inward* (``outward=False``) or *outward* (``outward=True``; such a mesh
needs Mitsuba's ``flip_normals=true`` to face the camera inside it).
"""
import numpy as np

from mi_plugins.verify import geometry

TriangleMesh = geometry.TriangleMesh


def quad(center, u, v, n=1):
    """The parallelogram center +- u +- v in n x n cells (2 n^2 triangles), normal u x v,
    uv coordinates covering [0, 1]^2."""
    c, u, v = (np.asarray(a, dtype=np.float64) for a in (center, u, v))
    s = np.linspace(-1.0, 1.0, int(n) + 1)
    grid = c + s[:, None, None] * u + s[None, :, None] * v          # (n+1, n+1, 3): i along u, j along v
    verts = grid.reshape(-1, 3)
    uv = np.stack(np.meshgrid((s + 1) / 2, (s + 1) / 2, indexing="ij"), axis=-1).reshape(-1, 2)
    idx = np.arange((n + 1) * (n + 1)).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()               # (i, j), (i+1, j)
    cc, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()                # (i+1, j+1), (i, j+1)
    faces = np.concatenate([np.stack([a, b, cc], 1), np.stack([a, cc, d], 1)])
    return TriangleMesh(verts, faces, uv)


def room_walls(half=1.0, n=1, center=(0.0, 0.0, 0.0), outward=False, skip=()):
    """The six faces of the box center +- half as {name: quad}, winding facing inward
    (outward=True: facing outward). Names: floor (y-), ceiling (y+), back (z-),
    front (z+), left (x-), right (x+); faces named in ``skip`` are left out."""
    h = float(half)
    c = np.asarray(center, dtype=np.float64)
    e = np.eye(3) * h
    # (name, axis, sign of the face's position): the inward normal is -sign * e_axis
    faces = {"left": (0, -1), "right": (0, 1), "floor": (1, -1), "ceiling": (1, 1), "back": (2, -1),
             "front": (2, 1)}
    out = {}
    for name, (axis, sign) in faces.items():
        if name in skip:
            continue
        normal = -sign * e[axis] / h                   # inward
        t = e[(axis + 1) % 3]
        b = np.cross(normal, t / h) * h                # t x b = normal * h^2 / h: faces inward
        mesh = quad(c + sign * e[axis], t, b, n)
        out[name] = mesh.flipped() if outward else mesh
    return out


def room(half=1.0, n=1, center=(0.0, 0.0, 0.0), outward=False, skip=()):
    """One mesh of the box's faces (see :func:`room_walls`)."""
    return TriangleMesh.concatenate(list(room_walls(half, n, center, outward, skip).values()))


def block(center, half_extents, n=1, y_rotation=0.0):
    """A closed box object (winding facing outward), rotated about the vertical axis."""
    hx, hy, hz = (float(a) for a in half_extents)
    walls = room_walls(1.0, n, outward=True)
    angle = np.radians(y_rotation)
    rot = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    mesh = TriangleMesh.concatenate(list(walls.values()))
    verts = (mesh.vertices * np.array([hx, hy, hz])) @ rot.T + np.asarray(center, dtype=np.float64)
    return TriangleMesh(verts, mesh.faces, mesh.uvs)


def shape(mesh, name, bsdf=None, emitter=None, flip_normals=False):
    """An ordinary Mitsuba ``ply`` shape dict for ``mesh`` (flat face normals)."""
    d = geometry.mesh_shape(mesh, "conformance_" + name)
    if flip_normals:
        d["flip_normals"] = True
    if bsdf is not None:
        d["bsdf"] = bsdf
    if emitter is not None:
        d["emitter"] = emitter
    return d


def diffuse(value):
    """A ``diffuse`` BSDF dict with an RGB (or grey) reflectance."""
    rgb = [float(value)] * 3 if np.isscalar(value) else [float(x) for x in value]
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": rgb}}


def area(value):
    """An ``area`` emitter dict with an RGB (or grey) radiance."""
    rgb = [float(value)] * 3 if np.isscalar(value) else [float(x) for x in value]
    return {"type": "area", "radiance": {"type": "rgb", "value": rgb}}
