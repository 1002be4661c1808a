"""Error versus wall time of `ray_bundle`, `stochastic_ray`, Mitsuba `path` and `ptracer`.

`ray_bundle` runs three times: as the paper's algorithm (``ray_bundle``), with
``first_shot=true`` (``ray_bundle_fs``: direct light by a light sample with MIS, the
bundles carrying only reflected radiance), and with ``first_shot=true,
average_diffuse=true`` (``ray_bundle_avg``: final gathering from the diffuse patches'
averages over chains and iterations), same resolution, chains and estimate.

Issue 4's benchmark: in one run, every integrator renders every scene at a ladder of
budgets (doubling until a render takes --seconds), and the RMSE of each image against
the exact image (analytic scenes) or a long `path` reference (the room) is recorded
against the wall time of the render. Every budget is rendered --repeats times (default
2, different seeds) and its RMSE is the root mean square over them: one image's RMSE is
a noisy statistic, above all for `ray_bundle`, whose pixels all gather from the same
chains (an error shared by the whole image). Scenes (all closed, all triangle meshes):

- furnace:  the furnace sphere mesh (diffuse albedo 0.5, emission 0.5: L = 1);
- sierpinski diffuse exact / diffuse simulated / phong n=10 simulated: the three
  constant-radiance scenes of the analytic-scenes paper's figure 4 (L = 1);
- room:     a closed Cornell-like room (white floor, back, front and ceiling, red and
  green side walls, a small emissive square in the ceiling, two blocks; a conforming
  mesh: no floor triangles under the blocks), camera inside; reference: a long `path`
  render (131072 spp) cached in benchmarks/.cache/.

Printed per scene: RMSE at the largest budget, mean image value against the exact
mean, log-log slope (-0.5 for an unbiased Monte Carlo method), RMSE ratio to `path`
at equal time (< 1: better than `path`), and rays traced per second relative to
`path`. Ray counts come from an untimed counting render per integrator and scene:
the Python integrators are instrumented (every `Scene.ray_intersect`,
`ray_intersect_preliminary` and `ray_test` call counts its active lanes), while
Mitsuba's C++ `path` and `ptracer` are counted with Python replicas of their loops
(same camera/light sampling, BSDF sampling, Russian roulette and shadow rays).
Rays per second: the better of a curve's two largest renders.
Timing: time.perf_counter around `mi.render` + conversion to numpy, after one
warm-up render per integrator; the LLVM compile time of kernels that miss Dr.Jit's
cache during a timed render (read from Dr.Jit's kernel history) is subtracted and
reported ("compile"). Every integrator's ladder (with its warm-up and ray count) runs in
a fresh process of its own: in one process, a Dr.Jit integrator renders 20-25 % slower
after Mitsuba's C++ `path` has rendered there (measured on the room: 1.15 s -> 1.40 s
per render, persistent; up to 2.5x after several C++ integrators), which would charge
the order of the ladders to the Python integrators. ``--no-isolate`` runs everything in
one process with the ladders interleaved (rung k of every integrator, then rung k + 1).
Writes a log-log plot (one panel per scene, plus the paper's figure 4 as RMSE of
`ray_bundle` versus iterations on the three Sierpinski scenes).

    python3 benchmarks/stochastic_iteration.py [--quick] [--seconds 2.5] [--resolution 32]
        [--scenes furnace,sierpinski_diffuse_exact,...] [--out benchmarks/stochastic_iteration.png]
"""
import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import time
import warnings

import drjit as dr
import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
import numpy as np  # noqa: E402

import mi_plugins  # noqa: E402,F401  (registers the plugins)
from mi_plugins import analytic  # noqa: E402
from mi_plugins import geometry as geo  # noqa: E402
from mi_plugins.analytic import constant_radiance as cr  # noqa: E402
from mi_plugins.analytic.case import AnalyticCase  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
WORKER_MARK = "@@worker-result "
CACHE = os.path.join(HERE, ".cache")
INTEGRATORS = ("path", "ptracer", "stochastic_ray", "ray_bundle", "ray_bundle_fs", "ray_bundle_avg")
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


# ---------------------------------------------------------------------------- integrators
class Method:
    """An integrator with a budget ladder: ``config(b)`` -> (integrator dict, spp)."""

    def __init__(self, name, ladder, config, budget_label):
        self.name, self.ladder, self.config, self.budget_label = name, ladder, config, budget_label


def methods(args):
    doubling = [2 ** k for k in range(20)]
    sr = dict(type="stochastic_ray", iterations=args.sr_iterations, burn_in=args.burn_in, max_depth=-1)
    rb_ladder = [args.burn_in + 8 * 2 ** k for k in range(16)]
    rb = lambda n, **extra: (dict(type="ray_bundle", iterations=n, burn_in=args.burn_in,
                                  resolution=args.bundle_resolution, chains=args.bundle_chains,
                                  estimate=args.bundle_estimate, **extra), 1)
    return {
        "path": Method("path", doubling, lambda b: (dict(type="path", max_depth=-1), b), "spp"),
        "ptracer": Method("ptracer", doubling, lambda b: (dict(type="ptracer", max_depth=-1), b), "spp"),
        "stochastic_ray": Method("stochastic_ray", doubling, lambda b: (dict(sr), b), "spp"),
        "ray_bundle": Method("ray_bundle", rb_ladder, rb, "iterations"),
        "ray_bundle_fs": Method("ray_bundle_fs", rb_ladder, lambda n: rb(n, first_shot=True), "iterations"),
        "ray_bundle_avg": Method("ray_bundle_avg", rb_ladder,
                                 lambda n: rb(n, first_shot=True, average_diffuse=True, gather_nee=args.gather_nee),
                                 "iterations"),
    }


# ---------------------------------------------------------------------------- timing
def compile_seconds():
    """LLVM compile time of the kernels that missed the cache since the last call."""
    return sum(k.get("backend_time", 0.0) for k in dr.kernel_history()
               if k.get("cache_hit", 1) == 0) / 1000.0


def timed_render(scene, spp, seed):
    dr.kernel_history()   # clears the history
    t0 = time.perf_counter()
    image = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64)
    wall = time.perf_counter() - t0
    comp = compile_seconds()
    return image, max(wall - comp, 1e-6), comp


def rmse(image, case):
    err2 = float(np.mean((image - case.expected()) ** 2))
    noise = getattr(case, "reference_noise", 0.0)
    # the reference's own noise adds in quadrature (independent): remove it (the
    # correction is capped at halving the raw RMSE)
    return math.sqrt(max(err2 - noise ** 2, 0.25 * err2))


def run_scene(case, meths, seconds, max_points, min_points, repeats):
    """Every integrator renders at its doubling ladder until one of its renders takes
    `seconds` (and at least `min_points` budgets); every budget is rendered `repeats`
    times with different seeds (RMSE: root mean square over them; seconds: mean). The
    ladders are interleaved (rung k of every integrator, then rung k+1) so that load
    from other processes affects all integrators alike. Returns
    {integrator: [dict(budget, seconds, compile, rmse, mean), ...]}."""
    scenes, curves = {}, {}
    for name, m in meths.items():   # warm-up: kernel compilation
        cfg, spp = m.config(m.ladder[0])
        scenes[name] = (cfg, case.scene(cfg))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mi.render(scenes[name][1], spp=spp, seed=999)
        curves[name] = []
    dr.kernel_history()
    active = list(meths)
    for k in range(max_points):
        for name in list(active):
            m = meths[name]
            cfg, spp = m.config(m.ladder[k])
            if cfg != scenes[name][0]:
                scenes[name] = (cfg, case.scene(cfg))
            renders = [timed_render(scenes[name][1], spp, seed=(k + 1) * 1000 + r) for r in range(repeats)]
            sec = float(np.mean([r[1] for r in renders]))
            curves[name].append(dict(budget=m.ladder[k], seconds=sec, compile=sum(r[2] for r in renders),
                                     rmse=math.sqrt(np.mean([rmse(r[0], case) ** 2 for r in renders])),
                                     mean=float(np.mean([r[0].mean() for r in renders]))))
            if sec >= seconds and k + 1 >= min_points:
                active.remove(name)
        if not active:
            break
    return curves


def rays_per_second(points, rays):
    """Rays per second of a curve: the better of its two largest renders (robust to a
    load spike from other processes; small renders are dominated by fixed overheads)."""
    return max(rays[p["budget"]] / p["seconds"] for p in points[-2:])


# ---------------------------------------------------------------------------- ray counting
def _count(mask, width):
    """Active lanes of a mask (None or a width-1 mask: all or none of ``width``)."""
    if mask is None:
        return width
    if dr.width(mask) == 1:
        return width if bool(mask[0]) else 0
    c = dr.count(mask)
    return int(c[0]) if dr.width(c) >= 1 and not isinstance(c, int) else int(c)


class RayCounter:
    """Counts the active lanes of every Python call to Scene.ray_intersect,
    ray_intersect_preliminary and ray_test, and the shadow rays of
    sample_emitter_direction(..., test_visibility=True) (loops run in evaluated mode
    meanwhile)."""

    METHODS = ("ray_intersect", "ray_intersect_preliminary", "ray_test", "sample_emitter_direction")

    def __init__(self):
        self.counts = {m: 0 for m in self.METHODS}

    @property
    def total(self):
        return sum(self.counts.values())

    def _wrap(self, name, original):
        counter = self

        def wrapper(scene, ray, *args, **kwargs):
            mask = None
            for value in list(args) + list(kwargs.values()):
                if isinstance(value, mi.Bool):
                    mask = value
            counter.counts[name] += _count(mask, dr.width(ray.o))
            return original(scene, ray, *args, **kwargs)

        def emitter_wrapper(scene, ref, sample, test_visibility=True, active=True):
            if test_visibility:   # one shadow ray per active lane
                counter.counts[name] += _count(active if isinstance(active, mi.Bool) else None, dr.width(ref.p))
            return original(scene, ref, sample, test_visibility, active)
        return emitter_wrapper if name == "sample_emitter_direction" else wrapper

    def __enter__(self):
        self.saved = {m: getattr(mi.Scene, m) for m in self.METHODS}
        for m in self.METHODS:
            setattr(mi.Scene, m, self._wrap(m, self.saved[m]))
        self.symbolic = dr.flag(dr.JitFlag.SymbolicLoops)
        dr.set_flag(dr.JitFlag.SymbolicLoops, False)
        return self

    def __exit__(self, *exc):
        for m, f in self.saved.items():
            setattr(mi.Scene, m, f)
        dr.set_flag(dr.JitFlag.SymbolicLoops, self.symbolic)


def _rng(n, seed):
    return mi.PCG32(n, initstate=mi.UInt64(seed * 7 + 3), initseq=mi.UInt64(dr.arange(mi.UInt32, n)))


def _camera_rays(scene, spp, rng):
    sensor = scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().crop_size())
    n = w * h * spp
    pixel = dr.arange(mi.UInt32, n) // spp
    pos = mi.Vector2f(mi.Float(pixel % w), mi.Float(pixel // w)) + mi.Vector2f(rng.next_float32(), rng.next_float32())
    ray, _ = sensor.sample_ray(0.0, 0.5, pos * dr.rcp(mi.ScalarVector2f(w, h)), mi.Point2f(0.5))
    return mi.Ray3f(ray)


def count_path_rays(scene, spp, rr_depth=5, max_iter=1000):
    """Replica of Mitsuba 3.9's `path` loop (max_depth -1): each iteration intersects the
    current ray (1 ray) and, at a smooth BSDF, samples an emitter (1 shadow ray where the
    emitter sample has a nonzero pdf); Russian roulette from depth rr_depth with
    q = min(max(throughput), 0.95)."""
    w, h = (int(v) for v in scene.sensors()[0].film().crop_size())
    n = w * h * spp
    rng = _rng(n, 1)
    ray = _camera_rays(scene, spp, rng)
    throughput, active, depth = mi.Color3f(1.0), dr.full(mi.Bool, True, n), mi.UInt32(0)
    ctx, rays = mi.BSDFContext(), 0
    for _ in range(max_iter):
        rays += _count(active, n)
        si = scene.ray_intersect(ray, active)
        active_next = active & si.is_valid()
        bsdf = si.bsdf(ray)
        active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds, _ = scene.sample_emitter_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), False, active_em)
        rays += _count(active_em & (ds.pdf != 0), n)
        bs, w = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), active_next)
        throughput = dr.select(active_next, throughput * mi.Color3f(w), throughput)
        ray = dr.select(active_next, si.spawn_ray(si.to_world(bs.wo)), ray)
        depth = dr.select(active_next, depth + 1, depth)
        t_max = dr.max(throughput)
        rr_prob = dr.minimum(t_max, 0.95)
        rr_active = depth >= rr_depth
        throughput = dr.select(rr_active, throughput / rr_prob, throughput)
        active = active_next & (~rr_active | (rng.next_float32() < rr_prob)) & (t_max != 0)
        dr.eval(ray, throughput, active, depth, rng.state)
        if _count(active, n) == 0:
            break
    return rays


def count_ptracer_rays(scene, spp, rr_depth=5, max_iter=1000):
    """Replica of Mitsuba 3.9's `ptracer` (max_depth -1), spp * W * H light paths: one
    shadow ray connecting the emitter sample to the camera, then per vertex one ray to the
    next vertex and one shadow ray to the camera where the camera sample is valid; Russian
    roulette after depth rr_depth with q = min(max(throughput), 0.95), the throughput
    starting at the emitter sample weight (power / pdf)."""
    sensor = scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().crop_size())
    n = w * h * spp
    rng = _rng(n, 2)
    rays = 0
    ray, weight, _ = scene.sample_emitter_ray(0.0, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()),
                                              mi.Point2f(rng.next_float32(), rng.next_float32()), True)
    it = dr.zeros(mi.Interaction3f, n)
    it.p = ray.o
    ds_e, _ = sensor.sample_direction(it, mi.Point2f(rng.next_float32(), rng.next_float32()), True)
    rays += _count(ds_e.pdf > 0, n)                       # sample_visible_emitters' connection
    throughput = mi.Color3f(weight)
    rays += n
    si = scene.ray_intersect(mi.Ray3f(ray), True)
    active = si.is_valid() & dr.any(throughput != 0)
    depth = mi.UInt32(1)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    for _ in range(max_iter):
        bsdf = si.bsdf(ray)
        ds, _ = sensor.sample_direction(si, mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        rays += _count(active & (ds.pdf > 0) & dr.any(throughput != 0), n)
        bs, bw = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32()), active)
        wo = si.to_world(bs.wo)
        wi_g, wo_g = dr.dot(si.n, -ray.d), dr.dot(si.n, wo)
        active &= (wi_g * mi.Frame3f.cos_theta(si.wi) > 0) & (wo_g * mi.Frame3f.cos_theta(bs.wo) > 0)
        corr = dr.abs(mi.Frame3f.cos_theta(si.wi) * wo_g / (mi.Frame3f.cos_theta(bs.wo) * wi_g))
        throughput = dr.select(active, throughput * mi.Color3f(bw) * corr, throughput)
        active &= dr.any(throughput != 0)
        ray = dr.select(active, si.spawn_ray(wo), ray)
        rays += _count(active, n)
        si = scene.ray_intersect(ray, active)
        depth = dr.select(active, depth + 1, depth)
        active &= si.is_valid()
        use_rr = depth > rr_depth
        q = dr.minimum(dr.max(throughput), 0.95)
        active &= ~use_rr | (rng.next_float32() < q)
        throughput = dr.select(use_rr, throughput / q, throughput)
        dr.eval(ray, si, throughput, active, depth, rng.state)
        if _count(active, n) == 0:
            break
    return rays


def count_rays(case, method, budgets):
    """{budget: rays traced by a render at that budget} plus a note on how it was counted."""
    b0 = method.ladder[0]
    cfg, spp = method.config(b0)
    scene = case.scene(cfg)
    if method.name == "path":
        per = count_path_rays(scene, 1)
        return {b: per * b for b in budgets}, "replica of path's loop, 1 spp, x spp"
    if method.name == "ptracer":
        per = count_ptracer_rays(scene, 1)
        return {b: per * b for b in budgets}, "replica of ptracer's loop, 1 spp, x spp"
    integ = scene.integrator()
    if method.name == "stochastic_ray":
        with RayCounter() as rc, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mi.render(scene, spp=spp, seed=5)
        return ({b: rc.total * b // spp for b in budgets},
                "instrumented, 1 spp x %d steps, x spp; %.2f rays per chain step"
                % (integ.iterations, rc.total / (dr.prod(scene.sensors()[0].film().crop_size()) * integ.iterations)))
    # ray_bundle: rays per burn-in iteration and per averaged iteration, from the progress hook
    marks = []
    integ.progress_callback = lambda done, total: marks.append(rc.total)
    integ.iterations, total = integ.burn_in + 4, integ.burn_in + 4
    try:
        with RayCounter() as rc, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mi.render(scene, spp=1, seed=5)
            prelim = rc.counts["ray_intersect_preliminary"]
    finally:
        integ.progress_callback = None
    marks = [0] + marks
    burn = (marks[integ.burn_in] - marks[0]) / max(integ.burn_in, 1)
    # (with average_diffuse the final gathering's passes, one per averaged iteration, come last)
    averaged = (marks[-1] - marks[integ.burn_in]) / (total - integ.burn_in)
    res = integ.resolution
    lines = math.pi / 4 * res * res * integ.chains   # lines inside the bounding disks (expected number)
    counts = {b: int(round(method.config(b)[0]["burn_in"] * burn + (b - integ.burn_in) * averaged)) for b in budgets}
    return counts, ("instrumented, %d bundle rays per iteration (%.1f hits per line), %d per averaged iteration"
                    % (burn, prelim / (total * lines) - 1.0, averaged))


# ---------------------------------------------------------------------------- analysis
def interp_loglog(points, t):
    """RMSE of a curve at time t (piecewise linear in log-log); outside the curve's range,
    extrapolated with slope -1/2 from the nearest end, flagged by the second value."""
    ts = np.log([p["seconds"] for p in points])
    es = np.log([p["rmse"] for p in points])
    order = np.argsort(ts)
    ts, es = ts[order], es[order]
    lt = math.log(t)
    if lt < ts[0]:
        return math.exp(es[0] - 0.5 * (lt - ts[0])), True
    if lt > ts[-1]:
        return math.exp(es[-1] - 0.5 * (lt - ts[-1])), True
    return math.exp(float(np.interp(lt, ts, es))), False


def slope(points):
    if len(points) < 2:
        return float("nan")
    return float(np.polyfit(np.log([p["seconds"] for p in points]), np.log([p["rmse"] for p in points]), 1)[0])


def monotone_warnings(scene, name, points):
    out = []
    for a, b in zip(points, points[1:]):
        if b["rmse"] >= a["rmse"]:
            out.append("WARNING %s / %s: RMSE does not decrease from budget %d (%.4g) to %d (%.4g)"
                       % (scene, name, a["budget"], a["rmse"], b["budget"], b["rmse"]))
    return out


# ---------------------------------------------------------------------------- plot
def plot(results, scenes, args):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401
    panels = list(scenes) + (["figure4"] if any(s in results for s in SIERPINSKI) else [])
    cols = 3
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.0 * cols, 4.0 * rows), squeeze=False)
    colors = {"path": "C0", "ptracer": "C1", "stochastic_ray": "C2", "ray_bundle": "C3", "ray_bundle_fs": "C4",
              "ray_bundle_avg": "C5"}
    for ax, panel in zip(axes.flat, panels):
        if panel == "figure4":
            for s, style in zip(SIERPINSKI, ("-o", "--s", ":^")):
                if s in results and "ray_bundle" in results[s]["curves"]:
                    pts = results[s]["curves"]["ray_bundle"]
                    ax.loglog([p["budget"] for p in pts], [p["rmse"] for p in pts], style, ms=3, label=SHORT[s])
            ax.set_xscale("log", base=2)
            ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_xlabel("ray_bundle iterations (burn-in included)")
            ax.set_title("paper fig. 4: ray_bundle error, Sierpinski scenes", fontsize=10)
        else:
            for name, pts in results[panel]["curves"].items():
                ax.loglog([p["seconds"] for p in pts], [p["rmse"] for p in pts], "-o", ms=3, color=colors[name],
                          label=name)
            ax.axvline(results[panel]["t_star"], color="0.7", lw=0.8, ls="--")
            ax.set_xlabel("seconds (compile time excluded)")
            ax.set_title(SHORT[panel], fontsize=10)
        ax.set_ylabel("RMSE")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    fig.suptitle("Error versus wall time, %d x %d px (%s)" % (args.resolution, args.resolution,
                                                               "quick" if args.quick else "default"))
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print("plot: %s" % args.out)


# ---------------------------------------------------------------------------- main
def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="short budgets (about a minute)")
    p.add_argument("--seconds", type=float, default=None,
                   help="stop a ladder once a render takes this long (default 2.5, quick 0.3)")
    p.add_argument("--resolution", type=int, default=32)
    p.add_argument("--scenes", default=",".join(SCENES), help="comma-separated subset of %s" % ", ".join(SCENES))
    p.add_argument("--integrators", default=",".join(INTEGRATORS))
    p.add_argument("--burn-in", type=int, default=8, help="burn_in of stochastic_ray and ray_bundle")
    p.add_argument("--sr-iterations", type=int, default=64, help="stochastic_ray steps per chain")
    p.add_argument("--bundle-resolution", type=int, default=32, help="ray_bundle lines per side")
    p.add_argument("--bundle-chains", type=int, default=64, help="ray_bundle chains run in lockstep")
    p.add_argument("--bundle-estimate", choices=("gather", "patch"), default="gather", help="ray_bundle image estimate")
    p.add_argument("--room-cells", type=int, default=8, help="quads per wall side in the room")
    p.add_argument("--room-mesh", choices=("conforming", "overlapping"), default="conforming",
                   help="conforming: the floor has no triangles under the blocks (default); overlapping: the "
                        "older room, rotated blocks standing on whole floor quads")
    p.add_argument("--ref-spp", type=int, default=None, help="room reference spp (default 131072, quick 4096)")
    p.add_argument("--max-points", type=int, default=14, help="most budgets per curve")
    p.add_argument("--min-points", type=int, default=None, help="fewest budgets per curve (default 3, quick 2)")
    p.add_argument("--repeats", type=int, default=2,
                   help="renders (seeds) per budget; their RMS error is the budget's RMSE (default 2)")
    p.add_argument("--out", default=os.path.join(HERE, "stochastic_iteration.png"))
    p.add_argument("--no-isolate", dest="isolate", action="store_false",
                   help="run all integrators in this process, ladders interleaved (default: one fresh process per "
                        "integrator and scene; a Dr.Jit integrator renders 20-25 %% slower in a process where "
                        "Mitsuba's C++ path has rendered, measured 1.15 s -> 1.40 s, and more after several)")
    p.add_argument("--no-gather-nee", dest="gather_nee", action="store_false",
                   help="ray_bundle_avg with gather_nee=false (direct light in the patch average)")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = p.parse_args()
    seconds = args.seconds or (0.3 if args.quick else 2.5)
    ref_spp = args.ref_spp or (4096 if args.quick else 131072)
    names = [s for s in args.scenes.split(",") if s]
    inames = [s for s in args.integrators.split(",") if s]
    for s in names:
        if s not in SCENES:
            p.error("unknown scene %r; choose from %s" % (s, ", ".join(SCENES)))
    for s in inames:
        if s not in INTEGRATORS:
            p.error("unknown integrator %r; choose from %s" % (s, ", ".join(INTEGRATORS)))

    t_start = time.perf_counter()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    meths = {k: v for k, v in methods(args).items() if k in inames}
    if args.worker:
        names = [args.worker.split(":")[0]]
    scenes = make_scenes(names, args.resolution, args.room_cells, ref_spp, args.room_mesh == "conforming")
    min_points = args.min_points or (2 if args.quick else 3)

    def measure(case, meths):
        """Ladders (interleaved), then ray counts: {integrator: curve}, {integrator: rays}, {integrator: how}."""
        curves = run_scene(case, meths, seconds, args.max_points, min_points, args.repeats)
        rays, how = {}, {}
        for mname, m in meths.items():
            rays[mname], how[mname] = count_rays(case, m, [pt["budget"] for pt in curves[mname]])
        return curves, rays, how

    if args.worker:
        sname, mname = args.worker.split(":")
        curves, rays, how = measure(scenes[sname], {mname: meths[mname]})
        print(WORKER_MARK + json.dumps(dict(curves=curves[mname], rays=rays[mname], how=how[mname])))
        return

    def run_isolated(sname, mname):
        """One integrator's ladder and ray count on one scene, in a fresh process."""
        out = subprocess.run([sys.executable, os.path.abspath(__file__), *sys.argv[1:], "--worker",
                              "%s:%s" % (sname, mname)], capture_output=True, text=True)
        lines = [l for l in out.stdout.splitlines() if l.startswith(WORKER_MARK)]
        if out.returncode != 0 or not lines:
            raise RuntimeError("worker %s:%s failed:\n%s\n%s" % (sname, mname, out.stdout[-2000:], out.stderr[-4000:]))
        data = json.loads(lines[-1][len(WORKER_MARK):])
        return data["curves"], {int(b): n for b, n in data["rays"].items()}, data["how"]
    print("stochastic_ray: iterations %d, burn_in %d; ray_bundle: burn_in %d, resolution %d, chains %d, estimate %s (ray_bundle_fs: the same with first_shot=true; ray_bundle_avg: first_shot=true, average_diffuse=true); ladders "
          "double until a render takes %.2f s, %d render(s) per budget; %d x %d px, llvm_ad_rgb, %d threads\n"
          % (args.sr_iterations, args.burn_in, args.burn_in, args.bundle_resolution, args.bundle_chains, args.bundle_estimate, seconds,
             args.repeats, args.resolution,
             args.resolution, dr.thread_count()))
    results, warns, notes = {}, [], []
    for sname, case in scenes.items():
        t0 = time.perf_counter()
        if args.isolate:
            curves, rays, how = {}, {}, {}
            for mname in meths:
                curves[mname], rays[mname], how[mname] = run_isolated(sname, mname)
        else:
            curves, rays, how = measure(case, meths)
        for mname in meths:
            warns += monotone_warnings(sname, mname, curves[mname])
        print("  [%s: %d renders and ray counting in %.1f s%s]"
              % (sname, sum(len(c) for c in curves.values()), time.perf_counter() - t0,
                 ", one process per integrator" if args.isolate else ""), flush=True)
        t_star = min(c[-1]["seconds"] for c in curves.values())
        results[sname] = dict(curves=curves, rays=rays, how=how, t_star=t_star)
        report_scene(sname, case, results[sname], meths, notes)
    summary(results, meths)
    for line in warns:
        print(line)
    if notes:
        print()
        for line in notes:
            print(line)
    plot(results, scenes, args)
    print("total run time %.1f s" % (time.perf_counter() - t_start))


def report_scene(sname, case, res, meths, notes):
    exact = case.expected()
    exact_mean = float(np.mean(exact))
    curves, t_star = res["curves"], res["t_star"]
    base_rmse = interp_loglog(curves["path"], t_star)[0] if "path" in curves else None
    base_rate = None
    if "path" in curves:
        base_rate = rays_per_second(curves["path"], res["rays"]["path"])
    print("\n%s (%s)%s; equal time t* = %.2f s" % (sname, SHORT[sname], "" if sname != "room" else
          ", RMSE vs reference (its noise %.4f removed)" % case.reference_noise, t_star))
    print("%-15s %13s %7s %9s %8s %8s %7s %9s %7s %9s %7s %8s" % (
        "integrator", "budgets", "seconds", "RMSE", "mean", "exact", "slope", "RMSE@t*", "/path",
        "Mrays/s", "/path", "compile"))
    for mname, pts in curves.items():
        last = pts[-1]
        at, extrap = interp_loglog(pts, t_star)
        rate = rays_per_second(pts, res["rays"][mname])
        budgets = "%d-%d %s" % (pts[0]["budget"], last["budget"], "spp" if meths[mname].budget_label == "spp" else "it")
        print("%-15s %13s %7.2f %9.5f %8.4f %8.4f %7.2f %8.5f%s %7s %9.2f %7s %7.1fs" % (
            mname, budgets, last["seconds"], last["rmse"], last["mean"], exact_mean, slope(pts), at,
            "*" if extrap else " ", "%.3f" % (at / base_rmse) if base_rmse else "-", rate / 1e6,
            "%.2f" % (rate / base_rate) if base_rate else "-", sum(p["compile"] for p in pts)))
    for mname in curves:
        extra = ""
        if mname.startswith("ray_bundle"):
            last = curves[mname][-1]
            extra = "; %.1f ms per iteration" % (1e3 * last["seconds"] / last["budget"])
        notes.append("rays %s / %s: %s%s" % (sname, mname, res["how"][mname], extra))


def summary(results, meths):
    if "path" not in meths:
        return
    print("\nTargets (issue 4): beat path at equal time on the diffuse closed scenes; >= 1/2 of path's rays/s")
    print("%-30s %-15s %12s %10s" % ("scene", "integrator", "RMSE/path@t*", "rays/s/path"))
    for sname, res in results.items():
        curves = res["curves"]
        base = interp_loglog(curves["path"], res["t_star"])[0]
        base_rate = rays_per_second(curves["path"], res["rays"]["path"])
        for mname in ("ray_bundle", "ray_bundle_fs", "ray_bundle_avg", "stochastic_ray"):
            if mname not in curves:
                continue
            pts = curves[mname]
            ratio = interp_loglog(pts, res["t_star"])[0] / base
            rate = rays_per_second(pts, res["rays"][mname]) / base_rate
            tag = "" if sname in DIFFUSE_SCENES else " (not a diffuse target)"
            print("%-30s %-15s %8.3f %-3s %8.2f %-3s%s" % (sname, mname, ratio, "ok" if ratio < 1 else "NO",
                                                          rate, "ok" if rate >= 0.5 else "NO", tag))


if __name__ == "__main__":
    main()
