"""Patches of Mitsuba's analytic shapes for the finite-element algorithms.

``rectangle``, ``disk``, ``sphere`` and ``cylinder`` have no triangles; their surface is
divided into patches along the (u, v) parameterisation that Mitsuba's ray intersections
report in ``si.uv``. A hit is mapped to its patch from ``si.uv`` alone, so the patches are
exact pieces of the true surface: no approximating triangles, the geometry the rays see
and the patches agree. Points of a patch are uniformly distributed in area:

==========  =========================  ====================================  ===========
shape       local point of (u, v)      cells (``nu`` x ``nv``)               local normal
==========  =========================  ====================================  ===========
rectangle   (2u - 1, 2v - 1, 0)        uniform in u and v (equal areas)      +z
disk        r = u, phi = 2 pi v        rings of equal area x sectors         +z
sphere      phi = 2 pi u, th = pi v    sectors x uniform bands in theta      outward
cylinder    phi = 2 pi u, z = v        sectors x uniform in z                outward
==========  =========================  ====================================  ===========

A shape's ``to_world`` maps the local point (its normal by the inverse transpose;
``flip_normals`` negates it). The tests check every formula against Mitsuba's own
intersections (position, uv and normal). The cell count follows the patch size ``h``
(default: the scene's bounding-box diagonal / :data:`CELLS_PER_DIAGONAL`): radiance is
constant per patch in these methods, so ``h`` is the spatial resolution of the solution
on these shapes, as the triangle size is on meshes. Unlike a triangle, a cell of the
sphere or cylinder is curved: a direction can face part of it only, so a value evaluated
at one of its points must be taken on the side the patch is used from (``ray_bundle``:
``transfer.on_side``; a point facing away otherwise zeroes the cell, -0.09 (h / r)^2 of
the power in the furnace sphere).
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base.queries import scene_bounds

#: default patch size: the scene's bounding-box diagonal divided by this
CELLS_PER_DIAGONAL = 24
#: analytic shapes (class names as Mitsuba prints them) -> kind code (0: a mesh)
KINDS = {"Rectangle": 1, "Disk": 2, "Sphere": 3, "Cylinder": 4}
#: cells per parameter at the most
MAX_CELLS = 64


def shape_kind(shape):
    """Mitsuba's class name of ``shape`` ('Rectangle', 'Sphere', 'PLYMesh', ...; class_name()
    where available: printing a mesh to read it costs milliseconds)."""
    if hasattr(shape, "class_name"):
        return shape.class_name()
    return str(shape).split("[", 1)[0].strip() or type(shape).__name__


#: relative tolerance of the checks of a sphere's or a cylinder's ``to_world`` (Mitsuba warns
#: beyond about 1e-6)
SCALE_TOLERANCE = 1e-4


def distortion(shape):
    """Why the patches of analytic ``shape`` cannot follow Mitsuba's surface, or None: a
    ``sphere`` whose ``to_world`` scales its axes differently or shears (Mitsuba 3.9.1
    warns, intersects a sphere of the first axis' length and returns hits whose uv do not
    lie on it: 57 of 1000 NaN), a ``cylinder`` whose cross-section is not a circle
    (Mitsuba intersects the ellipse but takes the first axis as the radius of its surface
    area, by which the patches' areas and its own light samples are scaled)."""
    kind = shape_kind(shape)
    if kind not in ("Sphere", "Cylinder"):
        return None
    m = np.array(mi.traverse(shape)["to_world"].matrix, dtype=np.float64).reshape(4, 4)[:3, :3]
    lengths = np.linalg.norm(m, axis=0)
    gram = m.T @ m / np.maximum(np.outer(lengths, lengths), 1e-300)
    axes = (0, 1, 2) if kind == "Sphere" else (0, 1)
    sheared = np.abs(gram - np.diag(np.diag(gram))).max() > SCALE_TOLERANCE
    uneven = np.ptp(lengths[list(axes)]) > SCALE_TOLERANCE * lengths[list(axes)].max()
    if not (sheared or uneven):
        return None
    what = "scales its axes by %s" % ", ".join("%.4g" % x for x in lengths) if uneven else "shears"
    if kind == "Sphere":
        return ("its to_world %s: Mitsuba warns, intersects a sphere of radius %.4g and gives its hits "
                "surface coordinates (uv) that do not lie on it, while the patches are laid out by them"
                % (what, lengths[0]))
    return ("its to_world %s: Mitsuba warns, intersects an elliptic or sheared tube but takes %.4g as "
            "the radius of its surface area, which scales the patches' areas and Mitsuba's own light "
            "samples on it" % (what, lengths[0]))


def local_point(kind, uv):
    """Local position and normal of the points with parameters ``uv`` on shapes of
    ``kind`` (JIT arrays, per lane)."""
    phi_u, phi_v, theta = dr.two_pi * uv.x, dr.two_pi * uv.y, dr.pi * uv.y
    su, cu = dr.sincos(phi_u)
    sv, cv = dr.sincos(phi_v)
    st, ct = dr.sincos(theta)
    rect = mi.Point3f(2.0 * uv.x - 1.0, 2.0 * uv.y - 1.0, 0.0)
    disk = mi.Point3f(uv.x * cv, uv.x * sv, 0.0)
    sphere = mi.Point3f(st * cu, st * su, ct)
    cylinder = mi.Point3f(cu, su, uv.y)
    p = dr.select(kind == 1, rect, dr.select(kind == 2, disk, dr.select(kind == 3, sphere, cylinder)))
    n = dr.select(kind <= 2, mi.Vector3f(0, 0, 1), dr.select(kind == 3, mi.Vector3f(sphere), mi.Vector3f(cu, su, 0.0)))
    return p, n


class ShapeFrame:
    """A shape's ``to_world`` as JIT-gatherable columns: point = o + ax x + ay y + az z,
    normal = normalize(nx x + ny y + nz z) (inverse transpose, negated by flip_normals)."""

    def __init__(self, shape):
        m = np.array(mi.traverse(shape)["to_world"].matrix, dtype=np.float64).reshape(4, 4)
        normal = np.linalg.inv(m[:3, :3]).T * (-1.0 if shape.has_flipped_normals() else 1.0)
        self.columns = np.concatenate([m[:3, 3], m[:3, 0], m[:3, 1], m[:3, 2],
                                       normal[:, 0], normal[:, 1], normal[:, 2]])

    @staticmethod
    def apply(columns, p, n):
        """World position and normal from per-lane ``columns`` (21 Float arrays)."""
        c = [mi.Vector3f(columns[3 * k], columns[3 * k + 1], columns[3 * k + 2]) for k in range(7)]
        world = mi.Point3f(c[0] + c[1] * p.x + c[2] * p.y + c[3] * p.z)
        return world, mi.Normal3f(dr.normalize(c[4] * n.x + c[5] * n.y + c[6] * n.z))


def _world(frame, kind, u, v):
    """numpy (n, 3) world points and normals of parameters ``u``, ``v`` on the shape of
    ``frame`` (a ShapeFrame)."""
    cols = frame.columns
    uv = mi.Point2f(np.asarray(u, dtype=np.float32), np.asarray(v, dtype=np.float32))
    p, n = ShapeFrame.apply([mi.Float(float(x)) for x in cols], *local_point(mi.UInt32(kind), uv))
    return np.array(p, dtype=np.float64).T, np.array(n, dtype=np.float64).T


def cell_centres(kind, bounds, columns):
    """numpy (n, 3) world centres and normals of the cells ``bounds`` (n, 4: u0, u1, v0,
    v1) of shapes of ``kind`` with frames ``columns`` (n, 21: :class:`ShapeFrame`): the
    points of median area in u and in v (a disk's rings and a sphere's bands are not
    uniform in their parameters)."""
    u0, u1, v0, v1 = np.asarray(bounds, dtype=np.float64).T
    mid_u = np.sqrt(0.5 * (u0 ** 2 + u1 ** 2)) if kind == 2 else 0.5 * (u0 + u1)
    mid_v = (np.arccos(0.5 * (np.cos(np.pi * v0) + np.cos(np.pi * v1))) / np.pi) if kind == 3 else 0.5 * (v0 + v1)
    uv = mi.Point2f(mid_u.astype(np.float32), mid_v.astype(np.float32))
    cols = [mi.Float(np.asarray(columns[:, k], dtype=np.float32)) for k in range(21)]
    p, n = ShapeFrame.apply(cols, *local_point(mi.UInt32(kind), uv))
    return np.array(p, dtype=np.float64).T.reshape(-1, 3), np.array(n, dtype=np.float64).T.reshape(-1, 3)


def _count(length, h, lo=1):
    return int(np.clip(np.ceil(length / h), lo, MAX_CELLS))


class ShapePatches:
    """The patches of one analytic shape: ``nu`` x ``nv`` cells (patch ``iv * nu + iu``)
    with their uv bounds, exact areas, and normals at the cell centres."""

    def __init__(self, shape, h):
        self.kind = kind = KINDS[shape_kind(shape)]
        self.frame = ShapeFrame(shape)
        c, pu, pv, opposite = _world(self.frame, kind, [0, 1, 0, 0.5], [0, 0, 1, 0])[0]
        if kind == 1:
            nu, nv = _count(np.linalg.norm(pu - c), h), _count(np.linalg.norm(pv - c), h)
        elif kind == 2:             # p(0, .) is the centre, p(1, 0) on the rim
            radius = np.linalg.norm(pu - c)
            nu, nv = _count(radius, h), _count(2 * np.pi * radius, h, lo=6)
        elif kind == 3:             # p(., 0) and p(., 1) are the poles
            nu = _count(np.pi * np.linalg.norm(pv - c), h, lo=8)
            nv = max(4, nu // 2)
        else:                       # p(0, 0) and p(0.5, 0): a diameter; v along the axis
            nu, nv = _count(np.pi * np.linalg.norm(opposite - c), h, lo=8), _count(np.linalg.norm(pv - c), h)
        self.nu, self.nv = nu, nv
        iu, iv = (a.ravel() for a in np.meshgrid(np.arange(nu), np.arange(nv)))
        u0, u1, v0, v1 = iu / nu, (iu + 1) / nu, iv / nv, (iv + 1) / nv
        if kind == 2:               # rings of equal area: r in [sqrt(k/n), sqrt((k+1)/n)]
            u0, u1 = np.sqrt(u0), np.sqrt(u1)
        self.bounds = np.stack([u0, u1, v0, v1], axis=1)
        self.surface_area = float(dr.slice(shape.surface_area()))
        self.areas = area_share(kind, self.bounds) * self.surface_area
        self.centres, self.normals = cell_centres(kind, self.bounds, np.tile(self.frame.columns, (len(u0), 1)))

    @property
    def count(self):
        return self.nu * self.nv


def area_share(kind, bounds):
    """The share of its shape's area of each cell with ``bounds`` (n, 4): u0, u1, v0, v1
    (numpy; the disk's u bounds are radii)."""
    u0, u1, v0, v1 = bounds.T
    if kind == 2:
        return (u1 ** 2 - u0 ** 2) * (v1 - v0)
    if kind == 3:                   # dphi / 2pi * (cos th0 - cos th1) / 2
        return (u1 - u0) * 0.5 * (np.cos(np.pi * v0) - np.cos(np.pi * v1))
    return (u1 - u0) * (v1 - v0)


def cell_coords(kind, nu, nv, uv):
    """(iu, iv, fu, fv): the cell of the points with parameters ``uv`` and their fractions
    within it along u (the radius on a disk, whose rings have equal areas) and v, in 0 .. 1."""
    disk = kind == 2
    u = dr.select(disk, uv.x * uv.x, uv.x)
    iu = dr.minimum(mi.UInt32(dr.maximum(u, 0.0) * mi.Float(nu)), nu - 1)
    iv = dr.minimum(mi.UInt32(dr.maximum(uv.y, 0.0) * mi.Float(nv)), nv - 1)
    u0, u1 = mi.Float(iu) / mi.Float(nu), mi.Float(iu + 1) / mi.Float(nu)
    u0, u1 = dr.select(disk, dr.sqrt(u0), u0), dr.select(disk, dr.sqrt(u1), u1)
    fu = dr.clip((uv.x - u0) / dr.maximum(u1 - u0, 1e-30), 0.0, 1.0)
    fv = dr.clip(uv.y * mi.Float(nv) - mi.Float(iv), 0.0, 1.0)
    return iu, iv, fu, fv


def sample_cell(kind, bounds, sample):
    """Parameters (u, v) of uniformly distributed area points of cells with ``bounds``
    (u0, u1, v0, v1 per lane) of shapes of ``kind``."""
    u0, u1, v0, v1 = bounds
    u = dr.select(kind == 2, dr.sqrt(dr.lerp(u0 * u0, u1 * u1, sample.x)), dr.lerp(u0, u1, sample.x))
    c0, c1 = dr.cos(dr.pi * v0), dr.cos(dr.pi * v1)
    v = dr.select(kind == 3, dr.acos(dr.clip(dr.lerp(c0, c1, sample.y), -1.0, 1.0)) / dr.pi,
                  dr.lerp(v0, v1, sample.y))
    return mi.Point2f(u, v)


def default_patch_size(scene):
    """The scene's bounding-box diagonal (:func:`scene_bounds`) / CELLS_PER_DIAGONAL."""
    lo, hi = scene_bounds(scene)
    return float(np.linalg.norm(hi - lo)) / CELLS_PER_DIAGONAL


def sub_triangle_coords(s, b1, b2):
    """(index, a, b): the sub-triangle holding (b1, b2) and the
    barycentric coordinates (a, b) of the point in it (weights of its corners 1 and 2,
    in the order of :func:`mi_plugins.patches.mesh_parts.sub_triangles`; clamped into the sub-triangle)."""
    x, y = b1 * mi.Float(s), b2 * mi.Float(s)
    j = dr.minimum(mi.UInt32(dr.maximum(y, 0.0)), s - 1)
    i = dr.minimum(mi.UInt32(dr.maximum(x, 0.0)), s - 1 - j)
    fx, fy = x - mi.Float(i), y - mi.Float(j)
    inverted = (fx + fy > 1.0) & (i + j < s - 1)
    a = dr.clip(dr.select(inverted, 1.0 - fx, fx), 0.0, 1.0)
    b = dr.clip(dr.select(inverted, 1.0 - fy, fy), 0.0, 1.0 - a)
    return j * (2 * s - j) + 2 * i + dr.select(inverted, 1, 0), a, b


def triangle_lattice(s):
    """The s x s similar sub-triangles of a triangle as integer lattice corners (i, j)
    (barycentric coordinates (s - i - j, i, j) / s), (s^2, 3, 2), with the parent's
    winding, row by row: row j (j = 0 .. s - 1) starts at j (2s - j); in it the upright
    triangle i is 2i, the inverted one 2i + 1. Integer corners give the points of an edge
    shared by two parents the same two non-zero weights on both: bit-identical positions."""
    j, i = (a.ravel() for a in np.meshgrid(np.arange(s), np.arange(s), indexing="ij"))
    first = j * (2 * s - j) + 2 * i
    corners = lambda *pts: np.stack([np.stack(p, axis=1) for p in pts], axis=1)
    out = np.empty((s * s, 3, 2), dtype=np.int64)
    up, inverted = i + j <= s - 1, i + j <= s - 2
    out[first[up]] = corners((i, j), (i + 1, j), (i, j + 1))[up]
    out[first[inverted] + 1] = corners((i + 1, j + 1), (i, j + 1), (i + 1, j))[inverted]
    return out
