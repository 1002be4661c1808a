"""The scenes of the real-scene benchmark (`real_scenes.py`): the Cornell box and two
heavier versions of it.

- ``cornell``: the Cornell box with the published measured geometry of the Cornell
  program of computer graphics (millimetres, scaled by SCALE: 0.001 by default, metres;
  see docs/real_scenes.md): floor, ceiling, back,
  left (red) and right (green) walls as 2 triangles per quad, the light (343-213 x
  332-227 mm) 0.1 mm under the ceiling, the short and the tall block as 5 visible quads
  each, front open; 32 triangles. Each surface is its own ``ply`` shape, oriented toward
  the free space (walls inward, blocks outward, light downward). Camera: the classic one,
  origin (278, 273, -800) mm looking along +z, 39.3 degrees field of view. Materials:
  the reflectances of Mitsuba's ``mi.cornell_box()``; the light emits RGB
  (18.4, 15.6, 8.0). Independent sampler, box filter.
- ``cornell_70k`` / ``cornell_1m``: the same box with a displaced geodesic sphere (each
  face of an icosahedron split into k^2 triangles: 20 k^2 = 69 620 or 1 003 520)
  standing on the floor in the free front-left corner, white.

:func:`scene_dict` builds a scene dict (meshes written once as content-addressed PLY
files by `mi_plugins.verify.geometry.mesh_file`); :func:`reference` renders (or reads from
benchmarks/.cache/) the long `path` reference; :func:`away_from_light` masks the pixels
near the visible light. Import after
``mi.set_variant('llvm_ad_rgb')``. Run the benchmark from the repository root:

    python3 benchmarks/real_scenes.py --quick
"""
import functools
import hashlib
import os
import time

import mitsuba as mi
import numpy as np

from mi_plugins.patches import tessellation
from mi_plugins.verify import geometry as geo

CACHE = os.path.join(os.path.dirname(os.path.abspath(__file__)), ".cache")
SCALE = 1e-3         # the Cornell data's millimetres -> scene units (the benchmark's --scale sets it)
WHITE = (0.885809, 0.698859, 0.666422)          # mi.cornell_box()'s reflectances
RED = (0.570068, 0.0430135, 0.0443706)
GREEN = (0.105421, 0.37798, 0.076425)
EMISSION = (18.4, 15.6, 8.0)
CAMERA = dict(origin=(278.0, 273.0, -800.0), target=(278.0, 273.0, -799.0), up=(0.0, 1.0, 0.0), fov=39.3)
RFILTER = "box"
BLOB_FREQUENCY = {"cornell": 0, "cornell_70k": 59, "cornell_1m": 224, "cornell_closed": 0}   # k: 20 k^2 triangles
#: the closed box: a white front wall at z = 0 and the camera inside, 3 cm behind it
CLOSED = {"cornell_closed"}
FRONT = [[556.0, 548.8, 0], [0, 548.8, 0], [0, 0, 0], [552.8, 0, 0]]
CLOSED_CAMERA = dict(origin=(278.0, 273.0, 30.0), target=(278.0, 273.0, 31.0), up=(0.0, 1.0, 0.0), fov=84.0)
SCENES = tuple(BLOB_FREQUENCY)

# Published Cornell box data (mm): one row per quad, four corners each.
WALLS = {
    "floor": [[552.8, 0, 0], [0, 0, 0], [0, 0, 559.2], [549.6, 0, 559.2]],
    "ceiling": [[556.0, 548.8, 0], [556.0, 548.8, 559.2], [0, 548.8, 559.2], [0, 548.8, 0]],
    "back": [[549.6, 0, 559.2], [0, 0, 559.2], [0, 548.8, 559.2], [556.0, 548.8, 559.2]],
    "right": [[0, 0, 559.2], [0, 0, 0], [0, 548.8, 0], [0, 548.8, 559.2]],             # green, x = 0
    "left": [[552.8, 0, 0], [549.6, 0, 559.2], [556.0, 548.8, 559.2], [556.0, 548.8, 0]],  # red
}
LIGHT = [[343.0, 548.7, 227.0], [343.0, 548.7, 332.0], [213.0, 548.7, 332.0], [213.0, 548.7, 227.0]]
BLOCKS = {  # top, then the four sides
    "short_block": [[[130, 165, 65], [82, 165, 225], [240, 165, 272], [290, 165, 114]],
                    [[290, 0, 114], [290, 165, 114], [240, 165, 272], [240, 0, 272]],
                    [[130, 0, 65], [130, 165, 65], [290, 165, 114], [290, 0, 114]],
                    [[82, 0, 225], [82, 165, 225], [130, 165, 65], [130, 0, 65]],
                    [[240, 0, 272], [240, 165, 272], [82, 165, 225], [82, 0, 225]]],
    "tall_block": [[[423, 330, 247], [265, 330, 296], [314, 330, 456], [472, 330, 406]],
                   [[423, 0, 247], [423, 330, 247], [472, 330, 406], [472, 0, 406]],
                   [[472, 0, 406], [472, 330, 406], [314, 330, 456], [314, 0, 456]],
                   [[314, 0, 456], [314, 330, 456], [265, 330, 296], [265, 0, 296]],
                   [[265, 0, 296], [265, 330, 296], [423, 330, 247], [423, 0, 247]]],
}
BOX_CENTER = (278.0, 274.4, 279.6)
BLOB = dict(center_xz=(410.0, 130.0), radius=75.0, lift=0.5)   # mm; clear of both blocks


def quads_mesh(quads, facing):
    """Quads (Q, 4, 3) in mm as 2 triangles each, scaled by SCALE, every triangle wound so that its
    normal points along ``facing(centroids)`` (an (n, 3) array of directions)."""
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 3) * SCALE
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    flip = np.einsum("ij,ij->i", normal, facing(tris.mean(axis=1))) < 0
    tris[flip] = tris[flip][:, ::-1]
    return geo._unshared_triangles(tris)


def blob(k):
    """The displaced geodesic sphere (20 k^2 triangles, outward), standing on the floor.
    Each icosahedron face (A, B, C) is split into the lattice points (k-i-j, i, j) / k
    (`mi_plugins.patches.tessellation.triangle_lattice`): k(k+1)/2 upward and k(k-1)/2 downward triangles. Points on a shared edge get the
    same two non-zero weights on both faces, hence bit-identical positions: no cracks."""
    ico = geo.icosphere(0, inward=False)                        # the icosahedron, outward
    lattice = tessellation.triangle_lattice(k)                           # (T, 3 vertices, 2) lattice coordinates (i, j)
    w = np.concatenate([(k - lattice.sum(-1))[..., None], lattice], axis=-1) / k       # (T, 3, 3)
    p = np.einsum("tvc,fcx->ftvx", w, ico.vertices[ico.faces]).reshape(-1, 3, 3)    # (20 T, 3, 3)
    d = p / np.linalg.norm(p, axis=-1, keepdims=True)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    r = (1.0 + 0.12 * np.sin(4 * x + 1) * np.sin(5 * y + 2) * np.sin(3 * z + 0.5)
         + 0.05 * np.sin(11 * x + 7 * z) * np.cos(9 * y) + 0.02 * np.sin(23 * y + 17 * x - 13 * z))
    p = d * (r * BLOB["radius"])[..., None]
    cx, cz = BLOB["center_xz"]
    p += np.array([cx, BLOB["lift"] - p[..., 1].min(), cz])
    return geo._unshared_triangles(p * SCALE)


@functools.lru_cache(maxsize=None)
def meshes(name):
    """{shape name: (TriangleMesh, reflectance)} of a scene; the light is separate."""
    inward = lambda c: np.asarray(BOX_CENTER) * SCALE - c
    out = {w: (quads_mesh(q, inward), RED if w == "left" else GREEN if w == "right" else WHITE)
           for w, q in WALLS.items()}
    if name in CLOSED:
        out["front"] = (quads_mesh(FRONT, inward), WHITE)
    for b, quads in BLOCKS.items():
        center = np.asarray(quads, dtype=np.float64).reshape(-1, 3).mean(axis=0) * SCALE
        out[b] = (quads_mesh(quads, lambda c: c - center), WHITE)
    if BLOB_FREQUENCY[name]:
        out["blob"] = (blob(BLOB_FREQUENCY[name]), WHITE)
    return out


def diffuse(rgb):
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(rgb)}}


def scene_dict(name, resolution):
    """The scene as a Mitsuba dict (no integrator) and its triangle count."""
    if name not in BLOB_FREQUENCY:
        raise ValueError("unknown scene %r; choose from %s" % (name, ", ".join(SCENES)))
    light = quads_mesh(LIGHT, lambda c: np.tile([0.0, -1.0, 0.0], (len(c), 1)))
    camera = CLOSED_CAMERA if name in CLOSED else CAMERA
    cam = {k: [c * SCALE for c in v] if k in ("origin", "target") else v for k, v in camera.items()}
    d = {"type": "scene",
         "sensor": {"type": "perspective", "fov": cam["fov"], "fov_axis": "x",
                    "to_world": mi.ScalarTransform4f().look_at(origin=cam["origin"], target=cam["target"],
                                                               up=cam["up"]),
                    "sampler": {"type": "independent", "sample_count": 1},
                    "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                             "pixel_format": "rgb", "rfilter": {"type": RFILTER}}},
         "light": dict(geo.mesh_shape(light, "cornell_light"), bsdf=diffuse(WHITE),
                       emitter={"type": "area", "radiance": {"type": "rgb", "value": list(EMISSION)}})}
    triangles = light.face_count
    for shape, (mesh, rgb) in meshes(name).items():
        d[shape] = dict(geo.mesh_shape(mesh, "cornell_" + shape), bsdf=diffuse(rgb))
        triangles += mesh.face_count
    return d, triangles


def reference_path(name, resolution, spp):
    """Cache file of a scene's reference: keyed by a hash of everything that sets the image."""
    d, _ = scene_dict(name, resolution)
    files = sorted(os.path.basename(v["filename"]) for v in d.values() if isinstance(v, dict) and "filename" in v)
    closed = (CLOSED_CAMERA,) if name in CLOSED else ()
    key = hashlib.sha1(repr((files, WHITE, RED, GREEN, EMISSION, CAMERA, RFILTER, SCALE, resolution, spp) + closed)
                       .encode()).hexdigest()[:12]
    return os.path.join(CACHE, "real_scenes_%s_%dpx_%dspp_%s.npy" % (name, resolution, spp, key))


def reference(name, resolution, spp, seed=1_000_000, render=True):
    """The `path` reference (max_depth -1) as (image, per-pixel variance of its noise),
    read from the cache or, with ``render``, rendered in chunks of at most 2^22 samples
    and cached as two independent halves (None when absent and not ``render``)."""
    path = reference_path(name, resolution, spp)
    if os.path.exists(path):
        halves = np.load(path)
    elif not render:
        return None
    else:
        t0 = time.perf_counter()
        d, _ = scene_dict(name, resolution)
        scene, integrator = mi.load_dict(d), mi.load_dict({"type": "path", "max_depth": -1})
        chunk = max(1, min(spp // 2, (1 << 22) // (resolution * resolution)))
        n = max(2, 2 * (spp // (2 * chunk)))
        images = [np.array(mi.render(scene, integrator=integrator, spp=chunk, seed=seed + c), dtype=np.float64)
                  for c in range(n)]
        halves = np.stack([np.mean(images[0::2], axis=0), np.mean(images[1::2], axis=0)])
        os.makedirs(CACHE, exist_ok=True)
        np.save(path, halves)
        print("reference %s: path %d spp in %.1f s, cached as %s" % (name, n * chunk, time.perf_counter() - t0,
                                                                     os.path.relpath(path)), flush=True)
    # independent halves: E[(a - b)^2] = 2 var(half) = 4 var(their mean), per pixel
    return halves.mean(axis=0), (halves[0] - halves[1]) ** 2 / 4.0


def away_from_light(ref):
    """Pixels none of whose 3 x 3 neighbours sees the light (the demo's mask: reference above
    1 in a colour channel; the light emits 18.4, the brightest lit surface pixels stay below 0.5)."""
    from mi_plugins.app.demo import away_from_light as mask
    return mask(ref)
