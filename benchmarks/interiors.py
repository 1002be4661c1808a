"""The interior benchmark scenes: procedurally generated rooms, none of them a Cornell box
(metres, z up, cameras at eye height looking across the room; `interior_bench.py` times
every method on them).

- ``room``: a furnished living room, 5 x 4 x 2.8 m: two ceiling panels and a window (an
  area light in a 20 cm deep opening) as lights; a table (rough-plastic top, aluminium
  legs), chairs, a sofa, a bookshelf full of books, a sideboard, a door, skirting boards,
  a rough-plastic teapot, a plant, a 69 620-triangle 'scanned' statue (a displaced
  geodesic sphere), a wooden floor (a generated bitmap);
- ``corridor``: an office corridor, 30 x 2.4 x 2.7 m, lit by 20 ceiling panels every
  1.5 m (most far from the camera); doors on both sides, benches, noticeboards, fire
  extinguishers, a plant, a tiled floor (a generated bitmap);
- ``skylight``: a room of 6 x 5 x 3 m with 25 cm thick walls, lit only by the sun and sky
  (``sunsky``, sun 40 degrees high in the south-west) through three window openings; a
  garden outside (16 x 16 m of grass walled by a 2.2 m hedge), a dining table, chairs, a bookshelf, a sofa, a plant;
- ``room_1m``: ``room`` with four more scanned sculptures on the furniture: 1 005 000
  triangles.

Materials: albedos 0.15-0.8, diffuse with some rough plastic and rough aluminium; lights:
``area`` rectangles (panels about 4 500 cd/m2, the window's sky a little less, in relative
units) or the sun and sky. :func:`scene_dict` gives the Mitsuba dict (no integrator;
meshes are cached PLY files, `interior_geometry.py`), :func:`camera_path` 60 views of a
walk at eye height (for walkthrough benchmarks), :func:`scene_key` a hash of everything
that sets a scene's image. Import after ``mi.set_variant(...)``.
"""
import hashlib
import json
import os

import mitsuba as mi
import numpy as np

import interior_furniture as furn
import interior_geometry as ig

SCENES = ("room", "corridor", "skylight", "room_1m")
SAMPLERS = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
EYE = 1.65
PANEL = [6.0, 5.7, 5.1]                  # warm-white ceiling panels
WINDOW = [3.0, 3.4, 4.0]                 # an overcast sky through the window
GARDEN = ((-5.0, -6.0), (11.0, 10.0))   # the skylight room's walled garden: (x0, y0), (x1, y1)
SUN = dict(direction=[-0.35, -0.65, 0.64], turbidity=3.0, albedo=0.2, scale=4.0)
PALETTE = {"walls": [0.72, 0.70, 0.66], "accent": [0.33, 0.43, 0.52], "ceiling": [0.80, 0.80, 0.78],
           "trim": [0.78, 0.77, 0.74], "door": [0.42, 0.28, 0.16], "dark": [0.17, 0.17, 0.19],
           "fabric": [0.22, 0.30, 0.47], "shelf": [0.60, 0.55, 0.47], "sideboard": [0.64, 0.64, 0.61],
           "statue": [0.56, 0.52, 0.46], "leaves": [0.12, 0.30, 0.08], "outside": [0.55, 0.52, 0.48],
           "ground": [0.20, 0.23, 0.14], "hedge": [0.08, 0.18, 0.06], "board": [0.55, 0.40, 0.25],
           "sculpture": [0.62, 0.46, 0.36],
           "books0": [0.55, 0.12, 0.10], "books1": [0.15, 0.25, 0.50], "books2": [0.70, 0.62, 0.40],
           "books3": [0.20, 0.40, 0.22], "books4": [0.35, 0.33, 0.32]}
GLOSSY = {"wood": ("roughplastic", [0.42, 0.27, 0.15], 0.2), "teapot": ("roughplastic", [0.55, 0.08, 0.06], 0.12),
          "pot": ("roughplastic", [0.50, 0.22, 0.12], 0.3), "red": ("roughplastic", [0.60, 0.05, 0.04], 0.15),
          "metal": ("roughconductor", "Al", 0.25)}
#: (floor group, texture function, metres per texture repeat)
TEXTURES = {"floor_wood": (furn.wood_planks, 2.0), "floor_tiles": (furn.floor_tiles, 2.4)}
T = mi.ScalarTransform4f


def material(group):
    if group in GLOSSY:
        kind, value, alpha = GLOSSY[group]
        if kind == "roughconductor":
            return {"type": kind, "material": value, "alpha": alpha}
        return {"type": kind, "diffuse_reflectance": {"type": "rgb", "value": value}, "alpha": alpha}
    if group in TEXTURES:
        make, _ = TEXTURES[group]
        return {"type": "diffuse", "reflectance": {"type": "bitmap", "bitmap": mi.Bitmap(make()), "raw": True,
                                                   "filter_type": "bilinear"}}
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": PALETTE[group]}}


def walls(size, into_room=True, openings=None, floor="floor_wood"):
    """Floor, ceiling and four walls of the box [0, size] (normals into the room), the
    walls' openings {'x0'|'x1'|'y0'|'y1': [(u0, v0, u1, v1)]} (u along the wall, v up)."""
    w, d, h = size
    openings = openings or {}
    faces = {floor: ig.plane_with_openings([0, 0, 0], [1, 0, 0], [0, 1, 0], w, d),
             "ceiling": ig.orient(ig.plane_with_openings([0, 0, h], [1, 0, 0], [0, 1, 0], w, d), [0, 0, -1])}
    sides = {"y0": ([0, 0, 0], [1, 0, 0], w, [0, 1, 0]), "y1": ([0, d, 0], [1, 0, 0], w, [0, -1, 0]),
             "x0": ([0, 0, 0], [0, 1, 0], d, [1, 0, 0]), "x1": ([w, 0, 0], [0, 1, 0], d, [-1, 0, 0])}
    parts = []
    for side, (origin, u, length, into) in sides.items():
        face = ig.plane_with_openings(origin, u, [0, 0, 1], length, h, openings.get(side, ()))
        parts.append({"walls": ig.orient(face, into)})
    return furn.merge(faces, *parts)


# ---------------------------------------------------------------------------- the scenes
def room_parts(million=False):
    size = (5.0, 4.0, 2.8)
    window = (1.2, 0.9, 2.8, 2.3)
    shell = walls(size, openings={"x1": [window]})
    shell["walls"] = np.concatenate([shell["walls"], ig.reveals([5.0, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], 0.2,
                                                                [window])])
    accent = np.abs(shell["walls"].mean(axis=1)[:, 1] - 4.0) < 1e-9
    shell["accent"], shell["walls"] = shell["walls"][accent], shell["walls"][~accent]
    parts = [shell, furn.table((2.7, 2.1)), furn.chair((2.3, 1.35), (0, 1)), furn.chair((3.1, 1.35), (0, 1)),
             furn.chair((2.7, 2.9), (0, -1)), furn.sofa((0.05, 1.6), (0.95, 3.5), "x0"),
             furn.bookshelf(1.15, 2.45, 4.0, -1, seed=3), furn.door("x", 0.0, 1, 0.3),
             furn.skirting(0.0, 0.0, 5.0, 4.0, gaps=[("x", 0.0, 0.24, 1.26)]), furn.plant(4.55, 0.45, seed=7),
             {"sideboard": ig.boxes([3.0, 3.55, 0.0], [4.6, 4.0, 0.8]),
              "statue": ig.scanned(59, 0.17, (3.45, 3.78, 0.8), seed=11, stretch=(0.9, 0.8, 1.3)),
              "teapot": ig.teapot((2.95, 2.3, 0.75), 0.2),
              "board": ig.boxes([0.0, 2.05, 1.3], [0.03, 3.05, 1.9])}]
    if million:     # 20 (100^2 + 110^2 + 120^2 + 100^2) = 930 000 more triangles
        parts.append({"sculpture": np.concatenate([
            ig.scanned(100, 0.12, (2.3, 1.95, 0.75), seed=21, stretch=(1.2, 1.0, 0.8)),
            ig.scanned(110, 0.15, (1.8, 3.8, 2.0), seed=22, stretch=(1.0, 0.9, 1.1)),
            ig.scanned(120, 0.30, (4.4, 2.9, 0.0), seed=23, stretch=(0.7, 0.7, 1.5)),
            ig.scanned(100, 0.14, (4.2, 3.78, 0.8), seed=24, stretch=(1.0, 0.9, 1.2))])})
    return furn.merge(*parts)


def corridor_parts():
    size = (30.0, 2.4, 2.7)
    doors_south, doors_north = [1.8 + 6 * i for i in range(5)], [4.8 + 6 * i for i in range(4)]
    gaps = [("y", 0.0, a - 0.06, a + 0.96) for a in doors_south] + [("y", 2.4, a - 0.06, a + 0.96)
                                                                    for a in doors_north]
    parts = [walls(size, floor="floor_tiles"), furn.skirting(0.0, 0.0, 30.0, 2.4, gaps=gaps),
             furn.plant(29.6, 2.0, seed=5, k=30, height=1.2)]
    parts += [furn.door("y", 0.0, 1, a) for a in doors_south] + [furn.door("y", 2.4, -1, a) for a in doors_north]
    for x in (3.0, 13.0, 25.0):             # benches along the north wall
        parts.append({"wood": ig.boxes([x, 1.95, 0.42], [x + 1.2, 2.35, 0.47]),
                      "metal": ig.cylinders([[x + a, y, 0.0] for a in (0.1, 1.1) for y in (2.0, 2.3)], 0.015,
                                            0.42, 8)})
    parts.append({"board": ig.boxes([[x, 0.0, 1.1] for x in (4.0, 10.0, 16.0, 22.0)],
                                    [[x + 1.0, 0.02, 1.8] for x in (4.0, 10.0, 16.0, 22.0)]),
                  "red": ig.cylinders([[x, 2.3, 0.0] for x in (9.3, 21.3)], 0.08, 0.5, 16)})
    return furn.merge(*parts)


def skylight_parts():
    size, t = (6.0, 5.0, 3.0), 0.25
    south, west = [(0.8, 0.8, 2.2, 2.4), (3.4, 0.8, 4.8, 2.4)], [(2.0, 0.8, 3.4, 2.4)]
    shell = walls(size, openings={"y0": south, "x0": west})
    shell["walls"] = np.concatenate([shell["walls"], ig.reveals([0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 1, 0], t, south),
                                     ig.reveals([0, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 0], t, west)])
    shift = lambda ops: [(a + t, b, c + t, d) for a, b, c, d in ops]
    w, d, h = size[0] + 2 * t, size[1] + 2 * t, size[2] + t
    outside = np.concatenate([
        ig.orient(ig.plane_with_openings([-t, -t, 0], [1, 0, 0], [0, 0, 1], w, h, shift(south)), [0, -1, 0]),
        ig.orient(ig.plane_with_openings([-t, -t, 0], [0, 1, 0], [0, 0, 1], d, h, shift(west)), [-1, 0, 0]),
        ig.orient(ig.plane_with_openings([size[0] + t, -t, 0], [0, 1, 0], [0, 0, 1], d, h), [1, 0, 0]),
        ig.orient(ig.plane_with_openings([-t, size[1] + t, 0], [1, 0, 0], [0, 0, 1], w, h), [0, 1, 0]),
        ig.plane_with_openings([-t, -t, size[2] + t], [1, 0, 0], [0, 1, 0], w, d)])
    (gx0, gy0), (gx1, gy1) = GARDEN
    ground = ig.plane_with_openings([gx0, gy0, 0.0], [1, 0, 0], [0, 1, 0], gx1 - gx0, gy1 - gy0,
                                    [(-t - gx0, -t - gy0, size[0] + t - gx0, size[1] + t - gy0)])
    hedge = ig.boxes([[gx0, gy0, 0], [gx1 - 0.6, gy0, 0], [gx0, gy0, 0], [gx0, gy1 - 0.6, 0]],
                     [[gx0 + 0.6, gy1, 2.2], [gx1, gy1, 2.2], [gx1, gy0 + 0.6, 2.2], [gx1, gy1, 2.2]])
    parts = [shell, {"outside": outside, "ground": ground, "hedge": hedge}, furn.table((3.2, 2.9), (1.8, 1.0)),
             furn.chair((2.8, 2.15), (0, 1)), furn.chair((3.6, 2.15), (0, 1)), furn.chair((2.8, 3.65), (0, -1)),
             furn.chair((3.6, 3.65), (0, -1)), furn.bookshelf(1.0, 2.6, 5.0, -1, seed=4),
             furn.sofa((5.05, 0.6), (5.95, 2.6), "x1"), furn.plant(0.5, 4.5, seed=9, k=40),
             furn.skirting(0.0, 0.0, 6.0, 5.0), {"teapot": ig.teapot((3.5, 3.0, 0.75), 0.2)}]
    return furn.merge(*parts)


#: the floor rectangle [0, x] x [0, y] of each scene's room
SIZES = {"room": (5.0, 4.0), "room_1m": (5.0, 4.0), "corridor": (30.0, 2.4), "skylight": (6.0, 5.0)}
PARTS = {"room": room_parts, "corridor": corridor_parts, "skylight": skylight_parts,
         "room_1m": lambda: room_parts(million=True)}
#: (origin, target) of each scene's camera, 70 (corridor: 60) degrees across
CAMERAS = {"room": ((0.45, 0.35, EYE), (4.3, 2.9, 1.0)), "room_1m": ((0.45, 0.35, EYE), (4.3, 2.9, 1.0)),
           "corridor": ((0.6, 1.2, EYE), (30.0, 1.35, 1.3)), "skylight": ((5.6, 4.6, EYE), (1.6, 0.6, 0.9))}
FOV = {"corridor": 60.0}
#: the walk of each scene's camera path: (origins (K, 3), targets (K, 3)) joined piecewise linearly
WALKS = {"room": ([(0.45, 0.35, EYE), (1.6, 0.8, EYE), (4.3, 0.9, EYE), (4.4, 3.0, EYE)],
                  [(4.3, 2.9, 1.0), (2.7, 2.1, 0.8), (1.5, 3.5, 1.2), (0.6, 1.0, 1.3)]),
         "corridor": ([(0.6, 1.2, EYE), (10.0, 1.1, EYE), (20.0, 1.3, EYE), (27.0, 1.2, EYE)],
                      [(30.0, 1.35, 1.3), (30.0, 0.8, 1.4), (30.0, 1.6, 1.4), (29.6, 2.0, 0.8)]),
         "skylight": ([(5.6, 4.6, EYE), (4.6, 1.5, EYE), (1.2, 1.2, EYE), (1.0, 4.3, EYE)],
                      [(1.6, 0.6, 0.9), (1.0, 4.0, 1.0), (5.0, 4.0, 1.0), (5.0, 0.8, 1.2)])}
WALKS["room_1m"] = WALKS["room"]


def _source():
    """A hash of the code that builds the meshes (this module and its two helpers)."""
    h = hashlib.sha1()
    for path in (__file__, ig.__file__, furn.__file__):
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:12]


_GROUPS = {}


def groups(name):
    """{group: cached PLY path} of a scene; the meshes are built (all of them, once per
    machine and version of the code) only when the scene's list of files is missing."""
    if name not in PARTS:
        raise ValueError("unknown interior scene %r; choose from %s" % (name, ", ".join(SCENES)))
    if name in _GROUPS:
        return dict(_GROUPS[name])
    source = _source()
    listing = os.path.join(ig.cache_dir(), "%s-%s.json" % (name, ig.key_of((name, source))))
    if os.path.exists(listing):
        with open(listing) as f:
            out = json.load(f)
    if not os.path.exists(listing) or not all(os.path.exists(p) for p in out.values()):
        parts = PARTS[name]()
        out = {g: ig.ply("%s_%s" % (name, g), (name, g, source), lambda t=t: t,
                         uv=(lambda p, g=g: p[:, :2] / TEXTURES[g][1]) if g in TEXTURES else None)
               for g, t in sorted(parts.items())}
        tmp = listing + ".%d.tmp" % os.getpid()
        with open(tmp, "w") as f:
            json.dump(out, f)
        os.replace(tmp, listing)
    _GROUPS[name] = out
    return dict(out)


def lights(name):
    """The emitters of a scene: ``area`` rectangles (shapes) or the sun and sky."""
    if name == "skylight":
        d = np.asarray(SUN["direction"], np.float64)
        return {"sky": {"type": "sunsky", "sun_direction": list(d / np.linalg.norm(d)), "turbidity": SUN["turbidity"],
                        "albedo": SUN["albedo"], "sun_scale": SUN["scale"], "sky_scale": SUN["scale"]}}
    rect = lambda to_world, radiance, rho: {"type": "rectangle", "to_world": to_world,
                                            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rho}},
                                            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": radiance}}}
    down = lambda x, y, z, sx, sy: T().translate([x, y, z]).rotate([1, 0, 0], 180).scale([sx, sy, 1])
    if name == "corridor":
        return {"panel%02d" % i: rect(down(0.75 + 1.5 * i, 1.2, 2.69, 0.3, 0.3), PANEL, 0.8) for i in range(20)}
    return {"panel0": rect(down(1.6, 2.0, 2.79, 0.6, 0.3), PANEL, 0.8),
            "panel1": rect(down(3.6, 2.0, 2.79, 0.6, 0.3), PANEL, 0.8),
            "window": rect(T().translate([5.2, 2.0, 1.6]).rotate([0, 1, 0], -90).scale([0.7, 0.8, 1]), WINDOW, 0.0)}


def look(origin, target):
    return T().look_at(origin=list(origin), target=list(target), up=[0, 0, 1])


def scene_dict(name, width=128, height=None, sampler="independent", spp=4, sensor_to_world=None):
    """The scene as a Mitsuba dict (no integrator): ``width`` x ``height`` px (default 3/4
    of the width), the sensor's ``sampler``, the camera of CAMERAS or ``sensor_to_world``."""
    if sampler not in SAMPLERS:
        raise ValueError("sampler=%r: choose from %s" % (sampler, ", ".join(SAMPLERS)))
    height = height or max(1, (3 * width) // 4)
    d = {"type": "scene",
         "sensor": {"type": "perspective", "fov": FOV.get(name, 70.0), "fov_axis": "x",
                    "to_world": sensor_to_world or look(*CAMERAS.get(name, ((0, 0, 0), (1, 0, 0)))),
                    "sampler": {"type": sampler, "sample_count": spp},
                    "film": {"type": "hdrfilm", "width": width, "height": height, "pixel_format": "rgb"}}}
    for group, path in groups(name).items():
        d[group] = {"type": "ply", "filename": path, "face_normals": True, "bsdf": material(group)}
    d.update(lights(name))
    return d


def triangles(name):
    """Triangle count of a scene (rectangle lights: 2 each)."""
    return sum(ig.ply_faces(p) for p in groups(name).values()) + 2 * sum(
        1 for v in lights(name).values() if v["type"] == "rectangle")


def camera_path(name, frames=60):
    """``frames`` sensor transforms along the scene's walk at eye height (WALKS), evenly
    spaced in the walk's parameter."""
    origins, targets = (np.asarray(a, np.float64) for a in WALKS[name])
    s = np.linspace(0.0, len(origins) - 1.0, frames)
    k = np.minimum(s.astype(int), len(origins) - 2)
    f = (s - k)[:, None]
    o, t = (1 - f) * origins[k] + f * origins[k + 1], (1 - f) * targets[k] + f * targets[k + 1]
    return [look(a, b) for a, b in zip(o, t)]


def scene_key(name, width, height=None):
    """A hash of everything that sets the scene's image at this size (the geometry files'
    contents, materials, textures, lights, camera)."""
    height = height or max(1, (3 * width) // 4)
    files = sorted((group, ig.file_digest(path)) for group, path in groups(name).items())
    parts = (name, width, height, files, PALETTE, GLOSSY, PANEL, WINDOW, SUN,
             CAMERAS.get(name), FOV.get(name), repr(lights(name)),
             sorted((k, f.__name__, r) for k, (f, r) in TEXTURES.items()))
    return hashlib.sha1(repr(parts).encode()).hexdigest()[:12]
