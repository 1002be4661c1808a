"""Per-patch light of a view-independent solution, shared by ``ray_bundle`` and
``qmc_lighttrace``: what every patch side receives directly from the lights, and the
BSDF and emission that turn irradiance into the radiance it sends.

- :func:`direct_irradiance`: the irradiance E_d (the shading frame's, as the solution's
  tables store it) of every patch side from the emitters, by next-event estimation at
  ``samples`` uniformly random points of the patch: one light sample and one
  cosine-distributed direction per point, combined by multiple importance sampling
  (the reflection of a white Lambertian surface there, times pi). Unbiased; its
  standard error per patch side comes with it. With ``children`` it also says what
  each child of every patch side receives (``mi_plugins.patches.refinement``).
- :func:`side_values`: f toward each side's normal (rho / pi on purely diffuse patches,
  0 elsewhere) and the emitted radiance along it, at each patch's centroid: the flat
  per-patch radiance Le + f (E_d + E) of the 'patches' display and of exported meshes.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins.base import seeds
from mi_plugins.patches.refinement import CHILDREN, child_index
from mi_plugins.light.direct import direct_light
from mi_plugins.solution.surfaces import Surfaces, reflectance_toward

#: Mitsuba's luminance weights of linear RGB (mi.luminance), for numpy patch values
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
#: random points per patch side of the direct irradiance
DIRECT_SAMPLES = 8
#: lanes of one kernel at the most (patch sides x samples are done in chunks)
CHUNK = 1 << 22


def white(table):
    """A white Lambertian BSDF reflecting on both sides, made once per patch table and
    held by it: a BSDF alive beyond its scene's lifetime would be among the plugins every
    later BSDF call traces, and a later scene's frozen steps could not be recorded."""
    if getattr(table, "white_bsdf", None) is None:
        table.white_bsdf = mi.load_dict({"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {
            "type": "rgb", "value": 1.0}}})
    return table.white_bsdf


def _side_points(table, index, side, rng):
    """Surface interactions at a uniformly random point of front patch ``index``, seen
    from the side ``side`` (0: the one its normal points to): the frame turned to face
    that side, si.wi along its normal."""
    si = table.surface_interaction(index, mi.Point2f(rng.next_float32(), rng.next_float32()))
    sign = 1.0 - 2.0 * mi.Float(side)
    si.n = mi.Normal3f(si.n * sign)
    si.sh_frame = mi.Frame3f(si.n)
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    return si


def direct_irradiance(scene, table, seed, samples=DIRECT_SAMPLES, children=False):
    """(mean, standard error), numpy (K, 2, 3) each: the direct irradiance of every front
    patch side of ``table`` (module docstring). With ``children``, also the points binned
    by the child holding them: the sums of their irradiance's luminance, of its square,
    and their counts, numpy (K, 2, 8) each (``refinement.from_points``)."""
    k = table.front_count
    total, squares = np.zeros((k * 2, 3)), np.zeros((k * 2, 3))
    bins = [np.zeros(k * 2 * CHILDREN) for _ in range(3)]
    if not scene.emitters() or not k:
        empty = (total.reshape(k, 2, 3), total.reshape(k, 2, 3))
        return empty + tuple(b.reshape(k, 2, CHILDREN) for b in bins) if children else empty
    lanes = k * 2 * samples
    bsdf = white(table)
    for start in range(0, lanes, CHUNK):        # chunks of lanes, not of rays
        n = min(CHUNK, lanes - start)
        lane = dr.arange(mi.UInt32, n) + dr.opaque(mi.UInt32, start)
        slot = lane // samples                  # patch side: 2 x patch + side
        rng = mi.PCG32(n, initstate=dr.opaque(mi.UInt64, seeds.stream(seed, "solution")),
                       initseq=mi.UInt64(lane))
        si = _side_points(table, slot // 2, slot % 2, rng)
        light = mi.Point2f(rng.next_float32(), rng.next_float32())
        value = dr.pi * direct_light(scene, si, bsdf, light, mi.Bool(True),
                                     (rng.next_float32(), mi.Point2f(rng.next_float32(), rng.next_float32())))
        sums, sq = dr.zeros(mi.Color3f, k * 2), dr.zeros(mi.Color3f, k * 2)
        dr.scatter_add(sums, value, slot)
        dr.scatter_add(sq, value * value, slot)
        child = [dr.zeros(mi.Float, k * 2 * CHILDREN) for _ in bins] if children else []
        if children:           # the point's irradiance, in its child
            where = slot * CHILDREN + child_index(table, table.locate(si))
            brought = mi.luminance(value)
            for b, x in zip(child, (brought, brought * brought, mi.Float(1.0))):
                dr.scatter_add(b, x, where)
        dr.eval(sums, sq, child)
        total += np.array(sums, dtype=np.float64).T
        squares += np.array(sq, dtype=np.float64).T
        for b, c in zip(bins, child):
            b += np.array(c, dtype=np.float64)
    mean = total / samples
    var = np.maximum(squares / samples - mean * mean, 0.0) / max(samples - 1, 1)
    out = (mean.reshape(k, 2, 3), np.sqrt(var).reshape(k, 2, 3))
    return out + tuple(b.reshape(k, 2, CHILDREN) for b in bins) if children else out


def side_values(scene, table):
    """(f toward the normal of each side, emitted radiance along it), numpy (K, 2, 3)
    each, at each front patch's centroid."""
    k = table.front_count
    si = table.surface_interaction(dr.arange(mi.UInt32, k), mi.Point2f(1.0 / 3.0, 1.0 / 3.0))
    emitter, bsdf = si.emitter(scene), si.bsdf()
    diffuse = Surfaces(scene).diffuse(si, True)
    f, e = [], []
    for z in (1.0, -1.0):
        si.wi = mi.Vector3f(0, 0, z)
        f.append(np.array(reflectance_toward(bsdf, si, diffuse), dtype=np.float64).T)
        e.append(np.array(emitter.eval(si, emitter != None), dtype=np.float64).T)  # noqa: E711
    return np.stack(f, axis=1), np.stack(e, axis=1)
