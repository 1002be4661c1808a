"""Global directions of ``ray_bundle``: one per chain and iteration.

'independent' directions are uniform on the sphere and independent from iteration to
iteration (what the paper requires), generated a block of iterations at a time
(:class:`DirectionStream`); with several chains and ``stratify_chains`` the
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

from mi_plugins.base import sequences

SEQUENCES = ("independent", "halton", "hammersley", "pi")


#: iterations whose directions are generated at once (fewer with many chains: a block holds
#: at most BLOCK_VALUES directions), so that a render never holds all its directions
BLOCK = 256
BLOCK_VALUES = 1 << 20


class DirectionStream:
    """The chains' global directions, iteration after iteration: :meth:`next` returns
    numpy (chains, 3). Generated in blocks of at most ``BLOCK`` iterations (memory
    O(chains x BLOCK), whatever the number of iterations of the render). ``rng``: a numpy
    Generator; ``antipodal``: the bundles are used both ways, so the stratified sets
    cover the upper hemisphere only; ``count``: the iterations of the render (the
    Hammersley set's size)."""

    def __init__(self, kind, chains, rng, stratify=False, antipodal=False, count=1):
        self.kind, self.chains, self.rng, self.antipodal = kind, int(chains), rng, antipodal
        self.stratify = stratify and self.chains > 1
        self.count, self.index = max(int(count), 1), 0
        self.block = max(1, min(BLOCK, BLOCK_VALUES // self.chains))
        self.buffer, self.pos = None, 0
        if kind in ("halton", "hammersley"):
            # each chain of a quasi-random sequence gets its own random Cranley-Patterson
            # shift (only of the second coordinate for Hammersley, whose ordering is the point)
            self.shift = rng.random((self.chains, 2))
            if kind == "hammersley":
                self.shift[:, 0] = 0.0
        elif kind == "pi":
            self.q = 1.0 + 99999.0 * rng.random(self.chains)
            self.pi_shift = rng.random((self.chains, 2))

    def next(self):
        if self.buffer is None or self.pos == len(self.buffer):
            self.buffer, self.pos = self._block(self.block), 0
        self.pos += 1
        return self.buffer[self.pos - 1]

    def _block(self, n):
        first, self.index = self.index, self.index + n
        if self.stratify:
            return stratified_direction_sets(n, self.chains, self.rng, self.antipodal)
        samples = self._samples(first, n)
        return uniform_sphere_directions(samples.reshape(-1, 2)).reshape(n, self.chains, 3)

    def _samples(self, first, n):
        """Points of [0,1)^2 that pick the directions of iterations first .. first + n - 1:
        numpy (n, chains, 2). 'independent': pseudo-random; 'halton': bases 2, 3 (points
        1, 2, ...); 'hammersley': ((k + 1/2) / count, radical inverse base 2), whose first
        coordinate only grows (the paper's failure case); 'pi': the paper's
        q_n = {(pi - 2) q_{n-1}} scheme."""
        if self.kind == "independent":
            return self.rng.random((n, self.chains, 2))
        if self.kind == "pi":
            return np.stack([self._pi_pair() for _ in range(n)])     # per iteration (scalar recurrence)
        index = dr.arange(mi.UInt32, n * 2) // 2 + first
        dim = dr.arange(mi.UInt32, n * 2) % 2
        if self.kind == "halton":
            pts = np.array(sequences.sample("halton", index + 1, dim, dims=2), dtype=np.float64).reshape(n, 2)
        else:
            pts = np.array(sequences.sample("hammersley", index, dim, dims=2, n=self.count), dtype=np.float64).reshape(n, 2)
            pts[:, 0] += 0.5 / self.count          # centred: (k + 1/2) / count
        return np.mod(pts[:, None, :] + self.shift[None], 1.0)

    def _pi_pair(self):
        """One 2-d point per chain of q_n = {(pi - 2) q_{n-1}} (kept modulo 100000 as in
        the paper; a value below 1 is restarted at random, because x -> 1.14 x leaves
        small values only slowly), consecutive values paired, with a random shift."""
        vals = []
        for _ in range(2):
            self.q = ((math.pi - 2.0) * self.q) % 100000.0
            low = self.q < 1.0
            if np.any(low):
                self.q = np.where(low, self.q + 1.0 + 99999.0 * self.rng.random(self.chains), self.q)
            vals.append(self.q - np.floor(self.q))
        return np.mod(np.stack(vals, axis=1) + self.pi_shift, 1.0)


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


def random_rotation(rng, count=None):
    """A uniformly distributed 3x3 rotation (Haar measure): the unit quaternion of four
    normal deviates; ``count`` of them (numpy (count, 3, 3)) when given."""
    q = rng.normal(size=(1 if count is None else count, 4))
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    r = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                  np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                  np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)
    return r[0] if count is None else r


def stratified_direction_sets(count, chains, rng, antipodal=False, shuffle=True):
    """numpy (count, chains, 3): per iteration the spherical Fibonacci set of ``chains``
    points (of the upper hemisphere with ``antipodal``), turned by a fresh uniformly
    random rotation and dealt to the chains in a fresh random order. Each chain's
    direction is uniform and independent from iteration to iteration; the directions of
    one iteration are stratified. The fresh order matters: with a fixed order every chain
    would turn by the same relative rotation between iterations, an error shared by all
    chains (``shuffle=False`` does that, to show it)."""
    base = spherical_fibonacci(chains, hemisphere=antipodal)
    order = (np.argsort(rng.random((count, chains)), axis=1) if shuffle
             else np.broadcast_to(np.arange(chains), (count, chains)))
    return np.einsum("mcj,mij->mci", base[order], random_rotation(rng, count))


def chain_directions(dirs):
    """numpy (chains, 3) -> Vector3f, one direction per chain, made opaque: a new
    direction must not recompile the kernels (a one-chain array would otherwise be a
    literal constant baked into them). Copied into memory of Dr.Jit's own (a gather):
    an array made from numpy may keep numpy's memory, whose alignment varies from call
    to call, and a frozen step would record itself again for every alignment."""
    flat = mi.Float(np.ascontiguousarray(np.asarray(dirs, dtype=np.float32).T.ravel()))
    n = len(dirs)
    index = dr.arange(mi.UInt32, n)
    d = mi.Vector3f(*(dr.gather(mi.Float, flat, index + c * n) for c in range(3)))
    dr.make_opaque(d)
    return d
