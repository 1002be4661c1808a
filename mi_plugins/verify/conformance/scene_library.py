"""The conformance scenes: ordinary Mitsuba scene dicts, written in Python.

Each builder takes ``resolution`` (the film is ``resolution`` x ``resolution`` pixels
with a box reconstruction filter, the sensor's sampler ``independent``) and returns a
scene dict without an integrator. :data:`SCENES` maps every name to ``(builder,
description)``; ``scenes()`` in the package returns {name: builder}. Nothing is downloaded: meshes are generated
(:mod:`.meshes`), the environment map is a small procedural bitmap.

Units: rooms are the box [-1, 1]^3 with y up; the camera looks along -z unless said.
"""
import mitsuba as mi
import numpy as np

from .meshes import area, block, diffuse, quad, room, room_walls, shape

WHITE, RED, GREEN = 0.6, (0.6, 0.1, 0.1), (0.1, 0.5, 0.1)


def sensor(origin, target, resolution, fov=40.0, up=(0, 1, 0)):
    return {"type": "perspective", "fov": float(fov), "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=list(up)),
            "sampler": {"type": "independent", "sample_count": 4},
            "film": {"type": "hdrfilm", "width": int(resolution), "height": int(resolution),
                     "pixel_format": "rgb", "rfilter": {"type": "box"}}}


def _front_camera(resolution, see_light=True):
    """Outside the open front of the room [-1, 1]^3, seeing its inside (tilted down by 4
    degrees with ``see_light=False``: the ceiling light is then out of the frame, so that
    its bright edge pixels do not dominate the noise)."""
    return sensor((0, 0, 3.6), (0, 0 if see_light else -0.25, 0), resolution, fov=34.0)


def _ceiling_light(size=0.25, radiance=12.0, n=1):
    """A small square area light just below the ceiling, facing down."""
    return shape(quad((0, 0.98, 0), (size, 0, 0), (0, 0, size), n), "ceiling_light_%g" % size,
                 diffuse(0.0), area(radiance))


def _cornell_walls(n=8, floor_bsdf=None, back_bsdf=None, left_bsdf=None):
    walls = room_walls(1.0, n, skip=("front",))
    bsdfs = {"floor": floor_bsdf or diffuse(WHITE), "ceiling": diffuse(WHITE), "back": back_bsdf or diffuse(WHITE),
             "left": left_bsdf or diffuse(RED), "right": diffuse(GREEN)}
    return {name: shape(walls[name], "cornell_%s_%d" % (name, n), bsdfs[name]) for name in bsdfs}


def cornell_mesh(resolution=16, light=True, see_light=False):
    """Cornell box of triangle meshes (8 x 8 cells per wall), open front, camera outside,
    a small area light below the ceiling (just out of the frame), a tall block inside."""
    d = {"type": "scene", "sensor": _front_camera(resolution, see_light), **_cornell_walls(),
         "block": shape(block((0.35, -0.4, -0.3), (0.3, 0.6, 0.3), 4, 20.0), "cornell_block", diffuse(WHITE))}
    if light:
        d["light"] = _ceiling_light()
    return d


def no_emitters(resolution=16):
    """The mesh Cornell box without its light: the image is black."""
    return cornell_mesh(resolution, light=False)


def cube_inside(resolution=16):
    """Mitsuba's ``cube`` with flip_normals, camera inside; diffuse 0.5 and area emission
    0.25 on every face: radiance 0.25 / (1 - 0.5) = 0.5 everywhere."""
    return {"type": "scene", "sensor": sensor((0.1, -0.2, 0.3), (0.6, 0.1, -1), resolution, fov=80.0),
            "cube": {"type": "cube", "flip_normals": True, "bsdf": diffuse(0.5), "emitter": area(0.25)}}


def _winding_room(resolution, outward):
    walls = room(1.0, 8, outward=outward)
    return {"type": "scene", "sensor": sensor((0.2, -0.3, 0.6), (-0.3, 0.0, -1), resolution, fov=75.0),
            "walls": shape(walls, "room_%s" % ("out" if outward else "in"), diffuse((0.5, 0.4, 0.3)),
                           flip_normals=outward),
            "light": _ceiling_light(0.5, 4.0)}


def winding_inward(resolution=16):
    """Closed room, one mesh wound to face inward (no flip_normals), camera inside."""
    return _winding_room(resolution, outward=False)


def winding_outward_flipped(resolution=16):
    """The same room wound to face outward, with flip_normals=true: the same image."""
    return _winding_room(resolution, outward=True)


def _sides_scene(resolution, twosided):
    """Two floor tiles, one facing up, one facing down; a light above, facing down, seen
    from behind by the camera above it."""
    tile = lambda name, normal_up, x: shape(
        quad((x, 0, 0), (0.45, 0, 0), (0, 0, -0.9) if normal_up else (0, 0, 0.9), 2), name + str(twosided),
        {"type": "twosided", "bsdf": diffuse(0.7)} if twosided else diffuse(0.7))
    return {"type": "scene", "sensor": sensor((0.0, 3.0, 0.4), (0, 0, 0), resolution, fov=50.0, up=(0, 0, -1)),
            "tile_up": tile("tile_up", True, -0.5), "tile_down": tile("tile_down", False, 0.5),
            "light": shape(quad((0.0, 1.2, 0.0), (0.3, 0, 0), (0, 0, 0.3)), "sides_light", diffuse(0.5), area(6.0))}


def one_sided(resolution=16):
    """One-sided surfaces: a tile and an area light seen from behind render black."""
    return _sides_scene(resolution, twosided=False)


def twosided(resolution=16):
    """The same scene with ``twosided`` tiles: the tile facing down is lit from above."""
    return _sides_scene(resolution, twosided=True)


def mitsuba_cornell(resolution=16):
    """``mi.cornell_box()`` (``rectangle`` walls and light, ``cube`` boxes), box filter; the
    camera is tilted down by 6.6 degrees so that the light is just out of the frame."""
    d = mi.cornell_box()
    d.pop("integrator", None)
    d["sensor"]["to_world"] = mi.ScalarTransform4f().look_at(origin=[0, 0, 3.9], target=[0, -0.45, 0], up=[0, 1, 0])
    film = d["sensor"]["film"]
    film.update(width=int(resolution), height=int(resolution), rfilter={"type": "box"})
    d["sensor"]["sampler"] = {"type": "independent", "sample_count": 4}
    return d


def analytic_shapes(resolution=16):
    """A ``rectangle`` floor, a ``sphere``, an open ``cylinder``, lit by a ``disk`` light."""
    return {"type": "scene", "sensor": sensor((0, 1.6, 3.2), (0, -0.3, 0), resolution, fov=45.0),
            "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], -90).scale(1.5)
                      .translate([0, 0, 0]), "bsdf": diffuse(WHITE)},
            "sphere": {"type": "sphere", "center": [-0.5, 0.4, 0.0], "radius": 0.4, "bsdf": diffuse(RED)},
            "cylinder": {"type": "cylinder", "p0": [0.6, 0.0, -0.2], "p1": [0.6, 0.8, -0.2], "radius": 0.3,
                         "bsdf": diffuse(GREEN)},
            "light": {"type": "disk", "to_world": mi.ScalarTransform4f().translate([0, 2.0, 0.3])
                      .rotate([1, 0, 0], 90).scale(0.4), "emitter": area(10.0)}}


def _open_floor(resolution, light):
    return {"type": "scene", "sensor": sensor((0, 1.2, 3.0), (0, 0, 0), resolution, fov=60.0),
            "floor": shape(quad((0, 0, 0), (1.5, 0, 0), (0, 0, -1.5), 4), "open_floor", diffuse((0.7, 0.5, 0.3))),
            "light": light}


def constant_env(resolution=16):
    """A floor under a ``constant`` sky (RGB radiance 1, 0.9, 0.8); the camera sees sky and floor."""
    return _open_floor(resolution, {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 0.9, 0.8]}})


def sky_bitmap(width=32, height=16):
    """A smooth procedural sky (latitude-longitude, RGB): brighter and bluer overhead,
    with a warm glow towards one side."""
    theta = (np.arange(height) + 0.5) / height * np.pi
    phi = (np.arange(width) + 0.5) / width * 2 * np.pi
    up = np.clip(np.cos(theta), 0, 1)[:, None]
    glow = np.exp(4 * (np.cos(phi - 1.0)[None, :] * np.sin(theta)[:, None] - 1))
    img = np.stack([0.3 + 0.4 * up + 2.0 * glow, 0.4 + 0.5 * up + 1.2 * glow, 0.6 + 0.8 * up + 0.4 * glow], -1)
    return mi.Bitmap(img.astype(np.float32))


def envmap_env(resolution=16):
    """The floor under an ``envmap`` sky (a procedural bitmap)."""
    return _open_floor(resolution, {"type": "envmap", "bitmap": sky_bitmap()})


def _lit_floor(resolution, light):
    return {"type": "scene", "sensor": sensor((0, 2.5, 2.5), (0, 0, 0), resolution, fov=55.0),
            "floor": shape(quad((0, 0, 0), (1.5, 0, 0), (0, 0, -1.5), 4), "lit_floor", diffuse(WHITE)),
            "light": light}


def point_light(resolution=16):
    """A diffuse floor under a ``point`` light."""
    return _lit_floor(resolution, {"type": "point", "position": [0.3, 1.0, 0.2],
                                   "intensity": {"type": "rgb", "value": [2.0, 1.8, 1.5]}})


def spot_light(resolution=16):
    """A diffuse floor under a ``spot`` light (a bright disc on the floor)."""
    return _lit_floor(resolution, {"type": "spot", "cutoff_angle": 30.0, "beam_width": 20.0,
                                   "to_world": mi.ScalarTransform4f().look_at([0.2, 1.5, 0.3], [0, 0, 0], [0, 0, 1]),
                                   "intensity": {"type": "rgb", "value": [6.0, 5.0, 4.0]}})


def directional_light(resolution=16):
    """A diffuse floor under a ``directional`` light (oblique, irradiance 1.2)."""
    return _lit_floor(resolution, {"type": "directional", "direction": [0.4, -1.0, -0.3],
                                   "irradiance": {"type": "rgb", "value": [1.2, 1.1, 1.0]}})


def closed_box_light_outside(resolution=16):
    """A closed two-sided box, camera inside, an area light outside facing it: black."""
    return {"type": "scene", "sensor": sensor((0.1, 0.0, 0.5), (0, 0, -1), resolution, fov=80.0),
            "box": shape(room(1.0, 2), "closed_box", {"type": "twosided", "bsdf": diffuse(WHITE)}),
            "light": shape(quad((0, 1.5, 0), (0.8, 0, 0), (0, 0, 0.8)), "outside_light", diffuse(0.0), area(20.0))}


def textured(resolution=16):
    """The mesh Cornell box with a ``checkerboard``-textured diffuse floor and back wall."""
    checker = {"type": "diffuse", "reflectance": {"type": "checkerboard", "color0": {"type": "rgb", "value": 0.15},
                                                  "color1": {"type": "rgb", "value": 0.8},
                                                  "to_uv": mi.ScalarTransform4f().scale([4, 4, 1])}}
    d = cornell_mesh(resolution, see_light=False)
    d.update(_cornell_walls(floor_bsdf=checker, back_bsdf=checker))
    return d


def glossy(resolution=16):
    """The mesh Cornell box with a ``roughplastic`` floor (alpha 0.3) and a
    ``roughconductor`` block (aluminium, alpha 0.5).

    (With alpha 0.3 on the block, ray_bundle's image is carried by rare spikes: its random
    global directions seldom fall in a narrow lobe seen by the camera, a documented limit
    of the method; measured per-run SD 2.1 % with outliers, against 1.05 % at alpha 0.5.)"""
    d = cornell_mesh(resolution, see_light=False)
    d.update(_cornell_walls(floor_bsdf={"type": "roughplastic", "alpha": 0.3, "diffuse_reflectance":
                                        {"type": "rgb", "value": [0.5, 0.5, 0.5]}}))
    d["block"]["bsdf"] = {"type": "roughconductor", "material": "Al", "alpha": 0.5}
    return d


def mirror(resolution=16):
    """The mesh Cornell box with an ideal mirror (``conductor``) as its back wall."""
    d = cornell_mesh(resolution, see_light=False)
    d.update(_cornell_walls(back_bsdf={"type": "conductor", "material": "none"}))
    return d


def glass(resolution=16):
    """The mesh Cornell box with a ``dielectric`` (glass) block instead of the white one."""
    d = cornell_mesh(resolution, see_light=False)
    d["block"] = {"type": "cube", "to_world": mi.ScalarTransform4f().translate([0.2, -0.6, 0.1]).scale(0.35),
                  "bsdf": {"type": "dielectric", "int_ior": 1.5}}
    return d


def mirror_lit(resolution=16):
    """A diffuse floor lit only through an ideal mirror the camera does not see: an area
    light facing up (below the mirror, never lighting the floor directly) and a mirror
    above it facing down."""
    d = _lit_floor(resolution, shape(quad((0, 0.3, 3.6), (1.0, 0, 0), (0, 0, -0.5)), "mirror_lit_light",
                                     diffuse(0.0), area(10.0)))
    d["sensor"] = sensor((0, 1.5, 2.8), (0, 0, -0.5), resolution, fov=55.0)
    d["mirror"] = shape(quad((0, 2.0, 1.7), (1.5, 0, 0), (0, 0, 0.6)), "mirror_lit_mirror",
                        {"type": "conductor", "material": "none"})
    return d


def _summary(f):
    """The first paragraph of a builder's docstring, on one line."""
    return " ".join((f.__doc__ or "").strip().split("\n\n")[0].split())


#: name -> (builder, description)
SCENES = {f.__name__: (f, _summary(f)) for f in (
    cornell_mesh, cube_inside, winding_inward, winding_outward_flipped, one_sided, twosided, mitsuba_cornell,
    analytic_shapes, constant_env, envmap_env, point_light, spot_light, directional_light,
    closed_box_light_outside, textured, glossy, mirror, glass, mirror_lit, no_emitters)}
