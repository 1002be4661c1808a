"""Global directions of ``ray_bundle``: one per chain and iteration.

'independent' directions are uniform on the sphere and independent from iteration to
iteration (what the paper requires); with several chains and ``stratify_chains`` the
directions of one iteration form an evenly spread set (a randomly rotated spherical
Fibonacci set dealt to the chains in a fresh random order), which keeps every chain's
sequence uniform and independent while the chain average converges faster. 'halton',
'hammersley' and 'pi' are the paper's 1-uniform sequences (section 6.1), kept to
reproduce its figure 7: they bias the result.
"""
import math

import drjit as dr
import mitsuba as mi
import numpy as np

from mi_plugins import qmc

SEQUENCES = ("independent", "halton", "hammersley", "pi")


def global_directions(kind, count, chains, rng, stratify=False, antipodal=False):
    """Directions of ``count`` iterations of ``chains`` chains: numpy (count, chains, 3).
    ``rng``: a numpy Generator; ``antipodal``: the bundles are used both ways, so the
    stratified sets cover the upper hemisphere only."""
    if stratify and chains > 1:
        return stratified_direction_sets(count, chains, rng, antipodal)
    return uniform_sphere_directions(direction_samples(kind, count, chains, rng).reshape(-1, 2)).reshape(
        count, chains, 3)


def direction_samples(kind, count, chains, rng):
    """``count`` points of [0,1)^2 per chain that pick the directions: numpy (count,
    chains, 2). 'independent': pseudo-random; 'halton': bases 2, 3 (points 1 .. count);
    'hammersley': (n/count, radical inverse base 2), whose first coordinate only grows
    (the paper's failure case); 'pi': the paper's q_n = {(pi - 2) q_{n-1}} scheme.
    Each chain of a quasi-random sequence gets its own random Cranley-Patterson shift
    (only of the second coordinate for Hammersley, whose ordering is the point)."""
    if kind == "independent":
        return rng.random((count, chains, 2))
    if kind == "pi":
        return np.stack([_pi_sequence(count, rng) for _ in range(chains)], axis=1)
    if kind == "halton":
        pts = qmc.points("halton", count, 2, start=1)
    else:
        pts = qmc.points("hammersley", count, 2)
        pts[:, 0] += 0.5 / count          # centred: (n + 1/2) / count
    shift = rng.random((chains, 2))
    if kind == "hammersley":
        shift[:, 0] = 0.0
    return np.mod(pts[:, None, :] + shift[None], 1.0)


def _pi_sequence(count, rng):
    """``count`` 2-d points of q_n = {(pi - 2) q_{n-1}} (kept modulo 100000 as in the
    paper; a value below 1 is restarted at random, because x -> 1.14 x leaves small
    values only slowly), consecutive values paired, with a random start and shift."""
    q = 1.0 + 99999.0 * rng.random()
    vals = []
    for _ in range(2 * count):   # a scalar recurrence: one step per value
        q = ((math.pi - 2.0) * q) % 100000.0
        if q < 1.0:
            q += 1.0 + 99999.0 * rng.random()
        vals.append(q - math.floor(q))
    return np.mod(np.array(vals).reshape(count, 2) + rng.random(2), 1.0)


def uniform_sphere_directions(samples):
    """Points of [0,1)^2 (numpy (n, 2)) -> uniform unit directions (n, 3): the first
    coordinate sets z = cos(theta), the second the azimuth, so Hammersley points sweep
    the polar angle monotonically (the paper's failure case)."""
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(samples[:, 1], samples[:, 0]))
    return np.stack([np.array(d.x), np.array(d.y), np.array(d.z)], axis=1).astype(np.float64)


def spherical_fibonacci(n, hemisphere=False):
    """``n`` evenly spread unit directions (numpy (n, 3)): equal-area bands in z (over
    z in [0, 1] with ``hemisphere``) with golden-angle azimuths."""
    k = np.arange(n) + 0.5
    z = k / n if hemisphere else 1.0 - 2.0 * k / n
    phi = math.pi * (3.0 - math.sqrt(5.0)) * k
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def random_rotation(rng):
    """A uniformly distributed 3x3 rotation (Haar measure): the unit quaternion of four
    normal deviates."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def stratified_direction_sets(count, chains, rng, antipodal=False, shuffle=True):
    """numpy (count, chains, 3): per iteration the spherical Fibonacci set of ``chains``
    points (of the upper hemisphere with ``antipodal``), turned by a fresh uniformly
    random rotation and dealt to the chains in a fresh random order. Each chain's
    direction is uniform and independent from iteration to iteration; the directions of
    one iteration are stratified. The fresh order matters: with a fixed order every chain
    would turn by the same relative rotation between iterations, an error shared by all
    chains (``shuffle=False`` does that, to show it)."""
    base = spherical_fibonacci(chains, hemisphere=antipodal)
    sets = np.empty((count, chains, 3))
    for m in range(count):   # per iteration (scalar set-up, not per ray)
        order = rng.permutation(chains) if shuffle else np.arange(chains)
        sets[m] = base[order] @ random_rotation(rng).T
    return sets


def chain_directions(dirs):
    """numpy (chains, 3) -> Vector3f, one direction per chain, made opaque: a new
    direction must not recompile the kernels (a one-chain array would otherwise be a
    literal constant baked into them)."""
    d = mi.Vector3f(*(mi.Float(np.ascontiguousarray(dirs[:, c], dtype=np.float32)) for c in range(3)))
    dr.make_opaque(d)
    return d
