"""Low-discrepancy and pseudo-random sequences, vectorised with Dr.Jit.

Every generator returns coordinate ``dim`` of the points with indices ``index``
(a ``mi.UInt32`` array; one lane per point), so millions of points are produced in
one kernel without Python loops over points:

=============== ============================================================
``halton``      radical inverse in the ``dim``-th prime (dims < ``MAX_HALTON_DIM``)
``faure``       Halton with Faure's digit permutations (Keller's report)
``sobol``       Sobol, Joe-Kuo direction numbers (dims < ``MAX_SOBOL_DIM``)
``hammersley``  dimension 0 is index / n, dimension d >= 1 is Halton's d - 1
``lcg``         48-bit linear congruential generator (drand48), one stream
``independent`` PCG32: stream = point index, its ``dim``-th number
=============== ============================================================

There is one implementation, :func:`sample`; the others are thin wrappers. The
dimension is a JIT value: an int ``dim`` is checked and passed opaquely (one compiled
kernel for every dimension), a ``mi.UInt32`` ``dim`` may differ per lane (the samplers).
``seed`` is an int or a ``mi.UInt32`` per lane; equal seeds give equal points.

Randomisation, keyed by :func:`hash32` (seed, dimension):

- ``scramble=True``: ``sobol``: Owen scrambling by hashing (nested uniform scramble,
  Laine-Karras permutation of the bit-reversed value); ``halton``: random digit
  permutations, one per dimension and digit position, drawn from the affine maps
  d -> (a d + c) mod b (a != 0): for a prime base these are pairwise uniform like
  uniformly random permutations, so every integrand has the same variance, and they
  are computed by hashing instead of tables; ``faure``: Faure's permutation followed by
  a random digit shift d -> (d + c) mod b per dimension and digit position (a random
  permutation from the full affine group would make scrambled Faure the same
  randomisation as scrambled Halton, erasing Faure's permutation; a shift keeps the
  differences between permuted digits). Every scramble maps b-adic elementary intervals
  onto such intervals and makes each point uniform on [0, 1)^s; ``lcg`` and
  ``independent`` ignore it (``seed`` seeds them);
- ``rotate=True`` on any sequence: Cranley-Patterson rotation (x + u) mod 1.

:func:`points` returns an (n, dims) numpy array for convenience.
"""
import functools
import math
import os

import drjit as dr
import mitsuba as mi
import numpy as np

SEQUENCES = ("halton", "faure", "sobol", "hammersley", "lcg", "independent")
MAX_HALTON_DIM = 256
MAX_SOBOL_DIM = 1024
_DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                     "sobol_joe_kuo_1024.npz")


class DimensionError(ValueError):
    """A dimension beyond what a sequence's tables support."""


def max_dim(sequence):
    return {"halton": MAX_HALTON_DIM, "faure": MAX_HALTON_DIM, "hammersley": MAX_HALTON_DIM + 1,
            "sobol": MAX_SOBOL_DIM}.get(sequence, 1 << 30)


# --------------------------------------------------------------------------- tables (numpy, cached)
@functools.lru_cache(maxsize=None)
def primes(count):
    """The first ``count`` primes."""
    limit = max(16, int(count * (math.log(count + 2) + math.log(math.log(count + 3))) + 10))
    sieve = np.ones(limit, dtype=bool)
    sieve[:2] = False
    for p in range(2, int(limit ** 0.5) + 1):
        if sieve[p]:
            sieve[p * p::p] = False
    return np.nonzero(sieve)[0][:count]


@functools.lru_cache(maxsize=None)
def faure_permutation(base):
    """Faure's permutation of {0, ..., b-1} (recursive construction)."""
    if base == 2:
        return np.array([0, 1])
    if base % 2 == 0:
        half = faure_permutation(base // 2)
        return np.concatenate([2 * half, 2 * half + 1])
    prev = faure_permutation(base - 1)
    c = (base - 1) // 2
    shifted = np.where(prev >= c, prev + 1, prev)
    return np.concatenate([shifted[:c], [c], shifted[c:]])


@functools.lru_cache(maxsize=None)
def _sobol_matrix():
    """(MAX_SOBOL_DIM, 32) uint32 direction numbers V[d, k] = m_k << (31 - k)."""
    data = np.load(_DATA)
    poly, vinit = data["poly"].astype(np.int64), data["vinit"].astype(np.int64)
    v = np.zeros((len(poly), 32), dtype=np.uint64)
    v[0] = [1 << (31 - k) for k in range(32)]
    for d in range(1, len(poly)):
        s = int(poly[d]).bit_length() - 1
        a = (int(poly[d]) >> 1) & ((1 << (s - 1)) - 1) if s > 1 else 0
        m = [0] * 33
        for k in range(1, s + 1):
            m[k] = int(vinit[d, k - 1])
        for k in range(s + 1, 33):
            value = m[k - s] ^ (m[k - s] << s)
            for j in range(1, s):
                if (a >> (s - 1 - j)) & 1:
                    value ^= m[k - j] << j
            m[k] = value
        v[d] = [(m[k + 1] << (31 - k)) & 0xFFFFFFFF for k in range(32)]
    return v.astype(np.uint32)


def _sobol_bytes(matrix):
    """(dims, 4, 256) uint32: for byte b of an index and each of its 256 values, the XOR of
    the direction numbers of its set bits, so that a coordinate is four lookups instead of
    32 (:func:`_sobol_bits`)."""
    out = np.zeros((matrix.shape[0], 4, 256), dtype=np.uint32)
    for byte in range(4):
        for bit in range(8):
            width = 1 << bit
            out[:, byte, width:2 * width] = out[:, byte, :width] ^ matrix[:, 8 * byte + bit, None]
    return out


@functools.lru_cache(maxsize=None)
def _tables(variant):
    """JIT tables of the current variant: Halton bases, offsets of each base's Faure
    permutation in the flat permutation table, that table, digits per base, Sobol
    byte tables [(dim * 4 + byte) * 256 + value] (:func:`_sobol_bytes`)."""
    bases = primes(MAX_HALTON_DIM).astype(np.uint32)
    offsets = np.concatenate([[0], np.cumsum(bases)[:-1]]).astype(np.uint32)
    perms = np.concatenate([faure_permutation(int(b)) for b in bases]).astype(np.uint32)
    digits = np.ceil(32 * np.log(2) / np.log(bases)).astype(np.uint32)   # of a 32-bit index
    return tuple(mi.UInt32(t) for t in (bases, offsets, perms, digits, _sobol_bytes(_sobol_matrix()).ravel()))


# --------------------------------------------------------------------------- hashing, JIT helpers
def hash32(*values):
    """The package's one 32-bit hash of ints and/or ``mi.UInt32`` arrays (then per lane):
    equal inputs give equal results, whatever their type (a Python int when all are ints)."""
    h = 0x9E3779B9
    for v in values:
        v = int(v) & 0xFFFFFFFF if isinstance(v, (int, np.integer)) else v
        h = ((h ^ v) * 0x85EBCA6B) & 0xFFFFFFFF
        h ^= h >> 13
        h = (h * 0xC2B2AE35) & 0xFFFFFFFF
        h ^= h >> 16
    return h


def to_unit(bits):
    """uint32 -> float in [0, 1) (24 significant bits, never 1.0)."""
    return mi.Float(bits >> 8) * (1.0 / (1 << 24))


def _jit(value, limit=None, name=None):
    """An int as an opaque mi.UInt32 (checked against ``limit`` when given), or the array."""
    if not isinstance(value, (int, np.integer)):
        return mi.UInt32(value)
    if limit is not None and not 0 <= value < limit:
        raise DimensionError("%s: dim=%r is outside the supported dimensions [0, %d)" % (name, value, limit))
    return dr.opaque(mi.UInt32, int(value) & 0xFFFFFFFF)


def _rotate(x, key):
    """Cranley-Patterson rotation (x + u) mod 1, u = hash of ``key``: the one rotation."""
    y = x + to_unit(hash32(key, 0xC0FFEE))
    return dr.select(y >= 1.0, y - 1.0, y)


def _reverse_bits(x):
    x = ((x >> 1) & 0x55555555) | ((x & 0x55555555) << 1)
    x = ((x >> 2) & 0x33333333) | ((x & 0x33333333) << 2)
    x = ((x >> 4) & 0x0F0F0F0F) | ((x & 0x0F0F0F0F) << 4)
    x = ((x >> 8) & 0x00FF00FF) | ((x & 0x00FF00FF) << 8)
    return (x >> 16) | (x << 16)


def owen_scramble(bits, key):
    """Nested uniform (Owen) scramble of 32-bit fixed-point values by hashing
    (Laine-Karras permutation applied to the bit-reversed value): the top bit is flipped
    by the key, every lower bit by a hash of the key and the bits above it, so aligned
    blocks of values map onto aligned blocks (used on Sobol coordinates, and by
    ``zsobol`` on sample indices)."""
    x = _reverse_bits(bits) + key
    for m in (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6):
        x ^= x * m
    return _reverse_bits(x)


# --------------------------------------------------------------------------- kernels (JIT dimension)
def _radical_inverse(index, d, faure, key):
    """Radical inverse of ``index`` in the ``d``-th prime: plain, with Faure's permutation,
    scrambled (``key``: random affine digit permutations; with ``faure``: digit shifts)."""
    bases, offsets, perms, digits, _ = _tables(mi.variant())
    base = dr.maximum(dr.gather(mi.UInt32, bases, d), 2)    # masked-out lanes gather 0
    offset, count = dr.gather(mi.UInt32, offsets, d), dr.gather(mi.UInt32, digits, d)
    inv_base = 1.0 / mi.Float64(base)

    def digit_step(k, rest, scale, result):
        digit = rest % base
        if faure:
            digit = dr.gather(mi.UInt32, perms, offset + digit)
        if key is not None:
            h = hash32(key, k)
            a = 1 if faure else (h // base) % (base - 1) + 1
            digit = (a * digit + h % base) % base
        scale = scale * inv_base
        return k + 1, rest // base, scale, result + mi.Float64(digit) * scale

    width = max(dr.width(index), dr.width(d), dr.width(key) if key is not None else 1)
    # a loop over the digits of a 32-bit index (ceil(32 / log2 b) of them; JIT, not unrolled)
    state = (dr.zeros(mi.UInt32, width), mi.UInt32(index) + dr.zeros(mi.UInt32, width),
             dr.ones(mi.Float64, width), dr.zeros(mi.Float64, width))
    result = dr.while_loop(state, lambda k, *_: k < count, digit_step)[3]
    return mi.Float(dr.minimum(result, 1.0 - 2.0 ** -24))


def _sobol_bits(index, d):
    """32-bit Sobol coordinate: XOR of the direction numbers of the index's set bits (by
    bytes: the four bytes' precomputed XORs)."""
    table = _tables(mi.variant())[4]
    bits = mi.UInt32(0)
    for byte in range(4):
        bits ^= dr.gather(mi.UInt32, table, (d * 4 + byte) * 256 + ((index >> (8 * byte)) & 0xFF))
    return bits


_LCG_A, _LCG_C, _LCG_MASK = 0x5DEECE66D, 0xB, (1 << 48) - 1


def _lcg_jump(k):
    """(A_k, C_k) with X_{n+k} = A_k X_n + C_k mod 2^48, vectorised over UInt64 ``k``."""
    acc_a, acc_c = mi.UInt64(1), mi.UInt64(0)
    a, c = _LCG_A, _LCG_C
    for bit in range(40):  # binary exponentiation over the bits of k (unrolled)
        take = ((k >> bit) & 1) != 0
        acc_a, acc_c = (dr.select(take, (acc_a * a) & _LCG_MASK, acc_a),
                        dr.select(take, (acc_c * a + c) & _LCG_MASK, acc_c))
        c = (c * (a + 1)) & _LCG_MASK
        a = (a * a) & _LCG_MASK
    return acc_a, acc_c


def sample(sequence, index, dim, dims=None, n=None, scramble=False, seed=0, rotate=False):
    """Coordinate ``dim`` of the points ``index`` of ``sequence`` (the implementation
    behind every generator of this module). ``dims``: numbers per point of ``lcg``
    (default dim + 1); ``n``: size of the ``hammersley`` set."""
    if sequence not in SEQUENCES:
        raise ValueError("sequence=%r: must be one of %s" % (sequence, ", ".join(SEQUENCES)))
    d, s, index = _jit(dim, max_dim(sequence), sequence), _jit(seed), mi.UInt32(index)
    key = hash32(s, d)                   # per (seed, dimension): scramble and rotation
    scramble_key = key if scramble else None
    if sequence in ("halton", "faure"):
        x = _radical_inverse(index, d, sequence == "faure", scramble_key)
    elif sequence == "sobol":
        bits = _sobol_bits(index, d)
        x = to_unit(owen_scramble(bits, key) if scramble else bits)
    elif sequence == "hammersley":
        if n is None or int(n) < 1:
            raise ValueError("hammersley: n=%r must be >= 1" % (n,))
        x = dr.select(d == 0, mi.Float(index) / float(n),
                      _radical_inverse(index, dr.maximum(d, 1) - 1, False, scramble_key))
    elif sequence == "lcg":
        if dims is None and not isinstance(dim, (int, np.integer)):
            raise ValueError("lcg: a JIT dimension needs dims (numbers per point)")
        step = mi.UInt64(index) * mi.UInt64(_jit(int(dim) + 1 if dims is None else dims)) + mi.UInt64(d) + 1
        a, c = _lcg_jump(step)
        state = (a * ((mi.UInt64(s) << 16) | 0x330E) + c) & _LCG_MASK   # srand48(seed)
        x = dr.minimum(mi.Float(mi.Float64(state) * (1.0 / float(1 << 48))), 1.0 - 2.0 ** -24)
    else:  # independent: number d of the PCG32 stream ``index`` (jump-ahead by d)
        rng = mi.PCG32(max(dr.width(index), dr.width(d)))
        rng.seed(mi.UInt64(hash32(s, 0x1D)), mi.UInt64(index))   # (the constructor would add the lane)
        rng = rng + mi.Int64(d)
        x = rng.next_float32()
    return _rotate(x, key) if rotate else x


def halton(index, dim, scramble=False, seed=0, rotate=False):
    """Coordinate ``dim`` of Halton points ``index`` (radical inverse in the dim-th prime)."""
    return sample("halton", index, dim, scramble=scramble, seed=seed, rotate=rotate)


def faure(index, dim, scramble=False, seed=0, rotate=False):
    """Halton with Faure's digit permutations (the same permutation for every digit)."""
    return sample("faure", index, dim, scramble=scramble, seed=seed, rotate=rotate)


def sobol(index, dim, scramble=False, seed=0, rotate=False):
    """Coordinate ``dim`` of Sobol points ``index`` (Joe-Kuo direction numbers)."""
    return sample("sobol", index, dim, scramble=scramble, seed=seed, rotate=rotate)


def hammersley(index, dim, n, scramble=False, seed=0, rotate=False):
    """Coordinate ``dim`` of the ``n``-point Hammersley set: index / n, then Halton."""
    return sample("hammersley", index, dim, n=n, scramble=scramble, seed=seed, rotate=rotate)


def lcg(index, dim, dims, seed=0, rotate=False):
    """drand48-style 48-bit LCG: point ``index`` uses numbers index*dims .. index*dims + dims - 1
    of one stream started from the state (seed << 16) | 0x330E (drand48's srand48)."""
    return sample("lcg", index, dim, dims=dims, seed=seed, rotate=rotate)


def independent(index, dim, seed=0, rotate=False):
    """PCG32: stream ``index`` (seeded from ``seed``), its ``dim``-th number."""
    return sample("independent", index, dim, seed=seed, rotate=rotate)


def points(sequence, n, dims, start=0, scramble=False, seed=0, rotate=False):
    """(n, dims) numpy array of points start .. start + n - 1 (one kernel for all dims)."""
    if int(dims) > max_dim(sequence):
        raise DimensionError("%s: dims=%d exceeds the %d supported dimensions" % (sequence, dims, max_dim(sequence)))
    lane = dr.arange(mi.UInt32, int(n) * int(dims))
    x = sample(sequence, lane // int(dims) + int(start), lane % int(dims), dims=int(dims), n=n,
               scramble=scramble, seed=seed, rotate=rotate)
    return np.array(x, dtype=np.float64).reshape(int(n), int(dims))
