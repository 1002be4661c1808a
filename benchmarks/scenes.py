"""The scenes of the stochastic-iteration benchmark (`stochastic_iteration.py`).

All closed, all triangle meshes:

- furnace:  the furnace sphere mesh (diffuse albedo 0.5, emission 0.5: L = 1);
- sierpinski diffuse exact / diffuse simulated / phong n=10 simulated: the three
  constant-radiance scenes of the analytic-scenes paper's figure 4 (L = 1);
- room:     a closed Cornell-like room (white floor, back, front and ceiling, red and
  green side walls, a small emissive square in the ceiling, two blocks; a conforming
  mesh: no floor triangles under the blocks), camera inside; reference: a long `path`
  render (131072 spp by default) cached in benchmarks/.cache/.

The analytic scenes compare against their exact images; the room is a :class:`RoomCase`
whose ``expected()`` is the cached reference. :func:`make_scenes` builds the selection.
Import after ``mi.set_variant('llvm_ad_rgb')`` (``mi_plugins`` requires a variant); the
benchmark's driver does so. Run the benchmark from the repository root:

    python3 benchmarks/stochastic_iteration.py --quick --scenes room
"""
import hashlib
import math
import os
import time

import mitsuba as mi
import numpy as np

from mi_plugins.verify import analytic
from mi_plugins.verify import geometry as geo
from mi_plugins.verify.analytic import constant_radiance as cr
from mi_plugins.verify.analytic.case import AnalyticCase

CACHE = os.path.join(os.path.dirname(os.path.abspath(__file__)), ".cache")
SCENES = ("furnace", "sierpinski_diffuse_exact", "sierpinski_diffuse_simulated", "sierpinski_phong_simulated", "room")
DIFFUSE_SCENES = ("furnace", "sierpinski_diffuse_exact", "sierpinski_diffuse_simulated", "room")
SIERPINSKI = SCENES[1:4]
SHORT = {"furnace": "furnace sphere mesh", "sierpinski_diffuse_exact": "Sierpinski diffuse, exact Le",
         "sierpinski_diffuse_simulated": "Sierpinski diffuse, simulated Le",
         "sierpinski_phong_simulated": "Sierpinski Phong n=10, simulated Le", "room": "closed Cornell-like room"}


# ---------------------------------------------------------------------------- the room
def quad_grid(corner, edge_u, edge_v, n, keep=None):
    """n x n grid of quads (2 triangles each) spanning corner + [0,1] edge_u + [0,1] edge_v;
    normals along edge_u x edge_v. ``keep(i, j)`` selects cells (default: all)."""
    corner, edge_u, edge_v = (np.asarray(x, dtype=np.float64) for x in (corner, edge_u, edge_v))
    tris = []
    for i in range(n):
        for j in range(n):
            if keep is not None and not keep(i, j):
                continue
            p00 = corner + edge_u * (i / n) + edge_v * (j / n)
            p10, p01 = p00 + edge_u / n, p00 + edge_v / n
            p11 = p10 + edge_v / n
            tris += [(p00, p10, p11), (p00, p11, p01)]
    return geo._unshared_triangles(np.array(tris))


def block(center, size, angle_deg, n=2):
    """Axis-aligned (then rotated about y) block standing on y = center[1] - size[1]/2,
    outward normals, no bottom face (it rests on the floor)."""
    hx, hy, hz = (0.5 * s for s in size)
    faces = [  # (corner, edge_u, edge_v) with edge_u x edge_v pointing outward
        ((-hx, hy, -hz), (0, 0, 2 * hz), (2 * hx, 0, 0)),     # top (+y)
        ((-hx, -hy, hz), (2 * hx, 0, 0), (0, 2 * hy, 0)),     # +z
        ((hx, -hy, -hz), (-2 * hx, 0, 0), (0, 2 * hy, 0)),    # -z
        ((hx, -hy, hz), (0, 0, -2 * hz), (0, 2 * hy, 0)),     # +x
        ((-hx, -hy, -hz), (0, 0, 2 * hz), (0, 2 * hy, 0)),    # -x
    ]
    mesh = geo.TriangleMesh.concatenate([quad_grid(c, u, v, n) for c, u, v in faces])
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    return geo.TriangleMesh(mesh.vertices @ rot.T + np.asarray(center), mesh.faces, mesh.uvs)


class RoomCase(AnalyticCase):
    """Closed room [-1, 1]^3, walls tessellated into ``cells`` x ``cells`` quads (ray_bundle
    keeps one radiance per triangle), light = the central 0.5 x 0.5 square of the ceiling
    (2 x 2 cells at the default 8 cells; finer cells only refine the tessellation).
    ``conforming`` (default): two upright blocks on whole floor cells, and no floor
    triangles under them, as a radiosity mesh should be (a patch partly hidden under a
    block spreads what its visible part receives over its whole area: ray_bundle then
    loses 0.6 % of the room's energy); false: the older room, blocks rotated by
    +-17 degrees standing on whole floor quads.
    ``expected()`` is the cached long `path` reference (set by :func:`room_reference`)."""

    LIGHT_RADIANCE = 50.0

    def __init__(self, resolution=32, cells=8, conforming=True):
        if cells % 8 or cells <= 0:
            raise ValueError("--room-cells=%d must be a positive multiple of 8 (the light is the central quarter "
                             "of the ceiling's side, whole cells)" % cells)
        n = cells
        diffuse = lambda rgb: {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(rgb)}}
        white, red, green = (0.73, 0.73, 0.73), (0.63, 0.065, 0.05), (0.14, 0.45, 0.09)
        is_light = lambda i, j: 3 * n // 8 <= i < 5 * n // 8 and 3 * n // 8 <= j < 5 * n // 8
        q = n // 8
        under = lambda i, j: (q <= i < 3 * q and q <= j < 3 * q) or (3 * q <= i < 5 * q and 5 * q <= j < 7 * q)
        walls = {  # name: (mesh, reflectance); normals point into the room
            "floor": (quad_grid((-1, -1, -1), (0, 0, 2), (2, 0, 0), n,
                                keep=(lambda i, j: not under(i, j)) if conforming else None), white),
            "ceiling": (quad_grid((-1, 1, -1), (2, 0, 0), (0, 0, 2), n, keep=lambda i, j: not is_light(i, j)), white),
            "back": (quad_grid((-1, -1, -1), (2, 0, 0), (0, 2, 0), n), white),
            "front": (quad_grid((-1, -1, 1), (0, 2, 0), (2, 0, 0), n), white),
            "left": (quad_grid((-1, -1, -1), (0, 2, 0), (0, 0, 2), n), red),
            "right": (quad_grid((1, -1, -1), (0, 0, 2), (0, 2, 0), n), green),
            "tall_block": (block((-0.5, -0.4, -0.5), (0.5, 1.2, 0.5), 0.0) if conforming else
                           block((-0.4, -0.4, -0.45), (0.5, 1.2, 0.5), 17.0), white),
            "short_block": (block((0.5, -0.7, 0.0), (0.5, 0.6, 0.5), 0.0) if conforming else
                            block((0.4, -0.7, -0.05), (0.5, 0.6, 0.5), -17.0), white),
        }
        surfaces = {}
        for name, (mesh, rgb) in walls.items():
            surfaces[name] = dict(geo.mesh_shape(mesh, "room%d%s_%s" % (n, "c" if conforming else "", name)), bsdf=diffuse(rgb))
        light = quad_grid((-1, 1, -1), (2, 0, 0), (0, 0, 2), n, keep=is_light)
        surfaces["light"] = dict(geo.mesh_shape(light, "room%d_light" % n), bsdf=diffuse(white),
                                 emitter={"type": "area", "radiance": {"type": "rgb", "value": [self.LIGHT_RADIANCE] * 3}})
        camera = ([0.0, 0.0, 0.95], [0.0, 0.0, -1.0], [0, 1, 0])
        super().__init__("room", surfaces, camera, resolution=resolution, fov=65.0,
                         params=dict(cells=cells, conforming=conforming), description="closed Cornell-like room, reference: long path render")
        self.reference = None
        self.reference_noise = 0.0   # RMS noise of the reference image (per pixel channel)

    def expected(self, max_depth=-1, supersampling=None):
        return self.reference


def room_reference(case, spp, chunk=1024, seed=10_000):
    """Long `path` reference of the room, cached as .npy; returns (image, noise RMS)."""
    files = [s["filename"] for s in case.surfaces.values()]
    key = hashlib.sha1(repr((case.resolution, case.fov, case.camera, spp, RoomCase.LIGHT_RADIANCE,
                             [open(f, "rb").read() for f in files])).encode()).hexdigest()[:12]
    path = os.path.join(CACHE, "room_reference_%dpx_%dspp_%s.npy" % (case.resolution, spp, key))
    if os.path.exists(path):
        halves = np.load(path)
        print("room reference: %s (cached)" % os.path.relpath(path))
    else:
        t0 = time.perf_counter()
        scene = case.scene({"type": "path", "max_depth": -1})
        chunk = min(chunk, spp // 2)
        n_chunks = max(2, spp // chunk)
        images = [np.array(mi.render(scene, spp=chunk, seed=seed + k), dtype=np.float64) for k in range(n_chunks)]
        halves = np.stack([np.mean(images[0::2], axis=0), np.mean(images[1::2], axis=0)])
        os.makedirs(CACHE, exist_ok=True)
        np.save(path, halves)
        print("room reference: path %d spp in %.1f s, cached as %s" % (n_chunks * chunk, time.perf_counter() - t0,
                                                                         os.path.relpath(path)))
    # the two halves are independent: var(a - b) = 2 var(half) = 4 var(mean)
    noise = float(np.sqrt(np.mean((halves[0] - halves[1]) ** 2) / 4.0))
    return halves.mean(axis=0), noise


# ---------------------------------------------------------------------------- scenes
def make_scenes(names, resolution, room_cells, ref_spp, conforming=True):
    scenes = {}
    for name in names:
        if name == "furnace":
            scenes[name] = analytic.furnace(0.5, 0.5, "sphere_mesh", resolution=resolution)
        elif name == "room":
            case = RoomCase(resolution, room_cells, conforming)
            case.reference, case.reference_noise = room_reference(case, ref_spp)
            scenes[name] = case
        else:
            scenes[name] = getattr(cr, name)(resolution=resolution)
    return scenes
