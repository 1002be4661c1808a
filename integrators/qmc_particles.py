"""``qmc_lighttrace``'s particle phase for one range of its sequence: the paths
start .. start + count - 1 deposit their power on the patch sides they hit, in 64-bit
fixed point (one kernel). Ranges are independent: the phase of a render is the sum of
its ranges' deposits, which is also how a distributed render splits it."""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import qmc

HEADROOM = 2.0 ** 12  #: fixed point: deposits above HEADROOM x the largest particle power are clamped
#: the most paths of one kernel (chunks bound the memory; the estimate is the same)
CHUNK = 1 << 20


def patch_side(table, si):
    """2 x patch + side of hits ``si``: side 0 is the one the normal points to."""
    return table.patch(si) * 2 + dr.select(mi.Frame3f.cos_theta(si.wi) < 0, 1, 0)


def trace_range(integ, scene, table, start, count, seed):
    """Deposits of paths start .. start + count - 1 of ``integ``'s sequence, in chunks of
    at most CHUNK paths summed in order: (reflected power per patch side (K, 2, 3),
    emitted power (3,)); zeros for a scene without emitters."""
    total, emitted, done = np.zeros((table.count, 2, 3)), np.zeros(3), 0
    while done < count and scene.emitters():
        n = min(CHUNK, count - done)
        deposit, power = trace_particles(integ, scene, table, start + done, n, int(seed))
        total, emitted, done = total + deposit, emitted + power, done + n
    return total, emitted


def trace_particles(integ, scene, table, start, count, seed):
    """Deposit the power of paths start .. start + count - 1 (one kernel); returns
    (reflected power per patch side, numpy (K, 2, 3), emitted power (3,))."""
    index = dr.arange(mi.UInt32, count) + dr.opaque(mi.UInt32, start)   # opaque: no recompiling
    u = lambda d: qmc.sample(integ.sequence, index, d, dims=integ.dims, scramble=integ.scramble, seed=seed)
    # light choice by dimension 0, rescaled and reused with dimension 1 for the position
    emitter_index, choice_weight, u0 = scene.sample_emitter(u(0))
    emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), emitter_index)
    ray, power = emitter.sample_ray(0.0, 0.5, mi.Point2f(u0, u(1)), mi.Point2f(u(2), u(3)))
    if any(mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) for e in scene.emitters()):
        # environment and directional lights: a direction, then a point of a disk across the scene
        # (Mitsuba 3.9's envmap sample_ray tilts that disk when the map is rotated: wrong power)
        sphere, it = scene.bbox().bounding_sphere(), dr.zeros(mi.Interaction3f)
        center, r, it.p = mi.Point3f(sphere.center), sphere.radius * 1.001 + 1e-4, mi.Point3f(sphere.center)
        infinite = mi.has_flag(emitter.flags(), mi.EmitterFlags.Infinite)
        ds, radiance = emitter.sample_direction(it, mi.Point2f(u(2), u(3)), infinite)
        disk = mi.warp.square_to_uniform_disk_concentric(mi.Point2f(u0, u(1)))
        origin = center + (ds.d + mi.Frame3f(ds.d).to_world(mi.Vector3f(disk.x, disk.y, 0))) * r
        ray = dr.select(infinite, mi.Ray3f(origin, -ds.d), ray)
        power = dr.select(infinite, radiance * (dr.pi * r * r), power)
    power = mi.Color3f(power * choice_weight)
    emitted = np.array(power, dtype=np.float64)
    # order-independent sums: 64-bit fixed point (integer atomics), a power-of-two scale
    # leaving room for count x (M + 1) deposits of up to HEADROOM x the largest power
    cap = 2.0 ** 63 / (count * (integ.max_depth + 1))
    scale = 2.0 ** np.floor(np.log2(cap / (HEADROOM * max(emitted.max(), 1e-30))))
    deposit = dr.zeros(mi.UInt64, 6 * table.count)    # [(patch * 2 + side) * 3 + channel]
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    state = (ray,                               # the particle's next ray
             power,                             # its power
             dr.zeros(mi.UInt32, count),        # surface hits so far (deposits up to M + 1)
             dr.any(power != 0))                # still travelling

    def body(ray, power, hits, active):
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid()
        bsdf = si.bsdf(ray)
        # deposit on the sides the BSDF reflects from (a one-sided BSDF hit from behind absorbs)
        side_flag = dr.select(mi.Frame3f.cos_theta(si.wi) < 0, mi.UInt32(mi.BSDFFlags.BackSide),
                              mi.UInt32(mi.BSDFFlags.FrontSide))
        lit = active & ((bsdf.flags() & side_flag) != 0)
        value = dr.minimum(power * bsdf.eval_diffuse_reflectance(si, active) * dr.opaque(mi.Float, scale),
                           dr.opaque(mi.Float, cap))
        slot = patch_side(table, si) * 3
        for c in range(3):
            dr.scatter_reduce(dr.ReduceOp.Add, deposit, mi.UInt64(value[c] + 0.5), slot + c, lit)
        active &= hits < integ.max_depth
        dim = 4 + 2 * dr.minimum(hits, max(integ.max_depth - 1, 0))     # dimensions of this bounce
        bs, weight = bsdf.sample(ctx, si, u(dim), mi.Point2f(u(dim), u(dim + 1)), active)
        power = dr.select(active, power * weight, 0.0)
        return si.spawn_ray(si.to_world(bs.wo)), power, hits + 1, active & dr.any(power != 0)

    dr.while_loop(state, lambda ray, power, hits, active: active, body)
    reflected = np.array(deposit, dtype=np.uint64).astype(np.float64) / scale
    return reflected.reshape(table.count, 2, 3), emitted.sum(axis=1)
