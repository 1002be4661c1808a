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
``independent`` PCG32, stream = point index, advanced to ``dim``
=============== ============================================================

Randomisation (``seed`` is an int; equal seeds give equal points):

- ``scramble=True`` on ``halton`` / ``faure``: random digit permutations (an
  independent random permutation of {0..b-1} per base and digit position);
- ``scramble=True`` on ``sobol``: Owen scrambling by hashing (nested uniform
  scramble, Laine-Karras style permutation of the bit-reversed value);
- ``rotate=True`` on any sequence: Cranley-Patterson rotation (x + u_d) mod 1.

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
_DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "sobol_joe_kuo_1024.npz")


class DimensionError(ValueError):
    """A dimension beyond what a sequence's tables support."""


def _check_dim(dim, limit, name):
    if not isinstance(dim, (int, np.integer)) or dim < 0 or dim >= limit:
        raise DimensionError("%s: dim=%r is outside the supported dimensions [0, %d)" % (name, dim, limit))


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


def _digits(base):
    """Digits of a 32-bit index in ``base``."""
    return int(math.ceil(32 * math.log(2) / math.log(base)))


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
    dims = len(poly)
    v = np.zeros((dims, 32), dtype=np.uint64)
    v[0] = [1 << (31 - k) for k in range(32)]
    for d in range(1, dims):
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


MAX_SOBOL_DIM = 1024


# --------------------------------------------------------------------------- helpers (Dr.Jit)
def _u32(index):
    return index if isinstance(index, mi.UInt32) else mi.UInt32(index)


def _to_unit(bits32):
    """uint32 -> float in [0, 1) (24 significant bits, never 1.0)."""
    return mi.Float(bits32 >> 8) * (1.0 / (1 << 24))


def _hash(*values):
    """32-bit hash of ints (Python) for seeding tables."""
    h = 0x9E3779B9
    for v in values:
        h = (h ^ (int(v) & 0xFFFFFFFF)) * 0x85EBCA6B & 0xFFFFFFFF
        h ^= h >> 13
    return h


def _reverse_bits(x):
    x = ((x >> 1) & 0x55555555) | ((x & 0x55555555) << 1)
    x = ((x >> 2) & 0x33333333) | ((x & 0x33333333) << 2)
    x = ((x >> 4) & 0x0F0F0F0F) | ((x & 0x0F0F0F0F) << 4)
    x = ((x >> 8) & 0x00FF00FF) | ((x & 0x00FF00FF) << 8)
    return (x >> 16) | (x << 16)


def owen_scramble(bits, seed):
    """Nested uniform (Owen) scramble of 32-bit fixed-point values by hashing
    (Laine-Karras permutation applied to the bit-reversed value)."""
    x = _reverse_bits(bits)
    x += seed
    x ^= x * 0x6C50B47C
    x ^= x * 0xB82F1E52
    x ^= x * 0xC7AFE638
    x ^= x * 0x8D22F6E6
    return _reverse_bits(x)


def _rotation(seed, dim):
    return (_hash(seed, dim, 0xC0FFEE) >> 8) / float(1 << 24)


def _rotate(x, seed, dim):
    y = x + _rotation(seed, dim)
    return dr.select(y >= 1.0, y - 1.0, y)


# --------------------------------------------------------------------------- sequences
def _radical_inverse(index, base, permutation=None, digit_permutations=None):
    """Radical inverse of ``index`` (UInt32) in ``base``; optional digit permutation
    (numpy array of length base) or per-digit permutations (numpy (digits, base))."""
    index = _u32(index)
    n_digits = _digits(base)
    result = dr.zeros(mi.Float64, dr.width(index))
    scale = 1.0
    perm_tables = None
    if digit_permutations is not None:
        perm_tables = mi.UInt32(np.asarray(digit_permutations, dtype=np.uint32).ravel())
    elif permutation is not None:
        perm_tables = mi.UInt32(np.asarray(permutation, dtype=np.uint32))
    rest = mi.UInt32(index)
    for k in range(n_digits):  # a loop over digit positions (unrolled), not over points
        digit = rest % base
        rest = rest // base
        if perm_tables is not None:
            offset = k * base if digit_permutations is not None else 0
            digit = dr.gather(mi.UInt32, perm_tables, digit + offset)
        scale /= base
        result += mi.Float64(digit) * scale
    return mi.Float(dr.minimum(result, 1.0 - 2.0 ** -24))


def _random_digit_permutations(base, seed, dim):
    rng = np.random.default_rng(_hash(seed, dim, base))
    return np.stack([rng.permutation(base) for _ in range(_digits(base))])


def halton(index, dim, scramble=False, seed=0, rotate=False):
    """Coordinate ``dim`` of Halton points ``index`` (radical inverse in the dim-th prime)."""
    _check_dim(dim, MAX_HALTON_DIM, "halton")
    base = int(primes(MAX_HALTON_DIM)[dim])
    perms = _random_digit_permutations(base, seed, dim) if scramble else None
    x = _radical_inverse(index, base, digit_permutations=perms)
    return _rotate(x, seed, dim) if rotate else x


def faure(index, dim, scramble=False, seed=0, rotate=False):
    """Halton with Faure's digit permutations (the same permutation for every digit)."""
    _check_dim(dim, MAX_HALTON_DIM, "faure")
    base = int(primes(MAX_HALTON_DIM)[dim])
    if scramble:
        # a random permutation composed with Faure's (still one fixed permutation per digit)
        perms = _random_digit_permutations(base, seed, dim)[:, faure_permutation(base)]
        x = _radical_inverse(index, base, digit_permutations=perms)
    else:
        x = _radical_inverse(index, base, permutation=faure_permutation(base))
    return _rotate(x, seed, dim) if rotate else x


def sobol_bits(index, dim):
    """32-bit Sobol coordinate (UInt32) of points ``index`` in dimension ``dim``."""
    _check_dim(dim, MAX_SOBOL_DIM, "sobol")
    v = _sobol_matrix()[dim]
    index = _u32(index)
    result = dr.zeros(mi.UInt32, dr.width(index))
    for k in range(32):  # one XOR per index bit (unrolled)
        result ^= dr.select(((index >> k) & 1) != 0, mi.UInt32(int(v[k])), mi.UInt32(0))
    return result


def sobol(index, dim, scramble=False, seed=0, rotate=False):
    """Coordinate ``dim`` of Sobol points ``index`` (Joe-Kuo direction numbers);
    ``scramble``: hash-based Owen scrambling."""
    bits = sobol_bits(index, dim)
    if scramble:
        bits = owen_scramble(bits, mi.UInt32(_hash(seed, dim, 0x5EED)))
    x = _to_unit(bits)
    return _rotate(x, seed, dim) if rotate else x


def hammersley(index, dim, n, scramble=False, seed=0, rotate=False):
    """Coordinate ``dim`` of the ``n``-point Hammersley set: index / n, then Halton."""
    if int(n) < 1:
        raise ValueError("hammersley: n=%r must be >= 1" % (n,))
    if dim == 0:
        x = mi.Float(_u32(index)) / float(n)
        return _rotate(x, seed, dim) if rotate else x
    return halton(index, dim - 1, scramble, seed, rotate)


_LCG_A, _LCG_C, _LCG_MASK = 0x5DEECE66D, 0xB, (1 << 48) - 1


def _lcg_jump(k):
    """(A_k, C_k) with X_{n+k} = A_k X_n + C_k mod 2^48, vectorised over UInt64 ``k``."""
    acc_a, acc_c = dr.ones(mi.UInt64, dr.width(k)), dr.zeros(mi.UInt64, dr.width(k))
    a, c = _LCG_A, _LCG_C
    for bit in range(40):  # binary exponentiation over the bits of k (unrolled)
        take = ((k >> bit) & 1) != 0
        new_a = (acc_a * a) & _LCG_MASK
        new_c = (acc_c * a + c) & _LCG_MASK
        acc_a, acc_c = dr.select(take, new_a, acc_a), dr.select(take, new_c, acc_c)
        c = (c * (a + 1)) & _LCG_MASK
        a = (a * a) & _LCG_MASK
    return acc_a, acc_c


def lcg(index, dim, dims, seed=0, rotate=False):
    """drand48-style 48-bit LCG: point ``index`` uses numbers index*dims .. index*dims + dims - 1
    of one stream started from the state (seed << 16) | 0x330E (drand48's srand48)."""
    k = mi.UInt64(_u32(index)) * int(dims) + int(dim) + 1
    a, c = _lcg_jump(k)
    x0 = ((int(seed) & 0xFFFFFFFF) << 16) | 0x330E
    state = (a * x0 + c) & _LCG_MASK
    x = mi.Float(mi.Float64(state) * (1.0 / float(1 << 48)))
    x = dr.minimum(x, 1.0 - 2.0 ** -24)
    return _rotate(x, seed, dim) if rotate else x


def independent(index, dim, seed=0, rotate=False):
    """PCG32: stream ``index`` (seeded from ``seed``), its ``dim``-th number."""
    index = _u32(index)
    rng = mi.PCG32(dr.width(index), mi.UInt64(_hash(seed, 0x1D)), mi.UInt64(index))
    for _ in range(int(dim)):  # advance the (vectorised) generators to number ``dim``
        rng.next_uint32()
    x = rng.next_float32()
    return _rotate(x, seed, dim) if rotate else x


def sample(sequence, index, dim, dims=None, n=None, scramble=False, seed=0, rotate=False):
    """Dispatch by name: coordinate ``dim`` of points ``index`` of ``sequence``."""
    if sequence == "halton":
        return halton(index, dim, scramble, seed, rotate)
    if sequence == "faure":
        return faure(index, dim, scramble, seed, rotate)
    if sequence == "sobol":
        return sobol(index, dim, scramble, seed, rotate)
    if sequence == "hammersley":
        return hammersley(index, dim, n, scramble, seed, rotate)
    if sequence == "lcg":
        return lcg(index, dim, dims if dims is not None else dim + 1, seed, rotate)
    if sequence == "independent":
        return independent(index, dim, seed, rotate)
    raise ValueError("sequence=%r: must be one of %s" % (sequence, ", ".join(SEQUENCES)))


def max_dim(sequence):
    return {"halton": MAX_HALTON_DIM, "faure": MAX_HALTON_DIM, "hammersley": MAX_HALTON_DIM + 1,
            "sobol": MAX_SOBOL_DIM}.get(sequence, 1 << 30)


def points(sequence, n, dims, start=0, scramble=False, seed=0, rotate=False):
    """(n, dims) numpy array of points start .. start + n - 1."""
    if int(dims) > max_dim(sequence):
        raise DimensionError("%s: dims=%d exceeds the %d supported dimensions" % (sequence, dims, max_dim(sequence)))
    index = dr.arange(mi.UInt32, int(start), int(start) + int(n))
    cols = [sample(sequence, index, d, dims=dims, n=n, scramble=scramble, seed=seed, rotate=rotate)
            for d in range(int(dims))]
    return np.stack([np.array(c, dtype=np.float64) for c in cols], axis=1)


# --------------------------------------------------------------------------- dynamic dimension
# Samplers advance their dimension inside symbolic loops, so the dimension is a JIT
# variable there: these variants take ``dim`` as a mi.UInt32 array.
@functools.lru_cache(maxsize=None)
def _halton_tables():
    """Flat digit tables for dims < MAX_HALTON_DIM: bases, per-dim offsets, Faure perms."""
    bases = primes(MAX_HALTON_DIM).astype(np.uint32)
    offsets = np.concatenate([[0], np.cumsum(bases)[:-1]]).astype(np.uint32)
    faure_perms = np.concatenate([faure_permutation(int(b)) for b in bases]).astype(np.uint32)
    return bases, offsets, faure_perms


def hash_u32(*values):
    """Vectorised 32-bit hash of UInt32 arrays (and ints)."""
    h = mi.UInt32(0x9E3779B9)
    for v in values:
        h = (h ^ mi.UInt32(v)) * 0x85EBCA6B
        h ^= h >> 13
        h *= 0xC2B2AE35
        h ^= h >> 16
    return h


def _hashed_unit(*values):
    return _to_unit(hash_u32(*values))


def sobol_dynamic(index, dim, scramble_seed=None):
    """Sobol coordinate for per-lane ``dim`` (UInt32 < MAX_SOBOL_DIM); optional per-lane Owen seed."""
    table = _sobol_dynamic_table()
    index = _u32(index)
    base = dim * 32
    result = dr.zeros(mi.UInt32, dr.width(index))
    for k in range(32):
        v = dr.gather(mi.UInt32, table, base + k)
        result ^= dr.select(((index >> k) & 1) != 0, v, 0)
    if scramble_seed is not None:
        result = owen_scramble(result, scramble_seed)
    return _to_unit(result)


@functools.lru_cache(maxsize=None)
def _sobol_dynamic_table():
    return mi.UInt32(_sobol_matrix().ravel())


@functools.lru_cache(maxsize=None)
def _random_permutation_table(seed):
    """Random digit permutations for every (dim, digit position), flattened: entry
    [offsets[dim] * 32 + k * base + digit]."""
    bases, offsets, _ = _halton_tables()
    tables = [np.concatenate([_random_digit_permutations(int(b), seed, d), np.zeros(
        (32 - _digits(int(b)), int(b)), dtype=np.int64)]) for d, b in enumerate(bases)]
    return mi.UInt32(np.concatenate([t.ravel() for t in tables]).astype(np.uint32))


def halton_dynamic(index, dim, faure=False, permutation_seed=None):
    """Halton coordinate for per-lane ``dim`` (UInt32 < MAX_HALTON_DIM): plain, with Faure's
    permutations (``faure``), or with random digit permutations (``permutation_seed``)."""
    bases, offsets, perms = _halton_tables()
    # masked-out lanes (inside symbolic loops) gather 0: keep the divisor >= 2
    base = dr.maximum(dr.gather(mi.UInt32, mi.UInt32(bases), dim), 2)
    offset = dr.gather(mi.UInt32, mi.UInt32(offsets), dim)
    perm_table = mi.UInt32(perms) if faure else None
    random_table = _random_permutation_table(int(permutation_seed)) if permutation_seed is not None else None
    rest = mi.UInt32(_u32(index))
    result = dr.zeros(mi.Float64, dr.width(rest))
    scale = dr.ones(mi.Float64, dr.width(rest))
    inv_base = 1.0 / mi.Float64(base)
    for k in range(32):  # enough digits for base 2; larger bases reach 0 earlier
        digit = rest % base
        rest = rest // base
        if faure:
            digit = dr.gather(mi.UInt32, perm_table, offset + digit)
        elif random_table is not None:
            digit = dr.gather(mi.UInt32, random_table, offset * 32 + k * base + digit)
        scale *= inv_base
        result += mi.Float64(digit) * scale
    return mi.Float(dr.minimum(result, 1.0 - 2.0 ** -24))


def lcg_dynamic(index, dim, dims, seed=0):
    """:func:`lcg` with ``dim``/``dims`` as JIT values (one kernel for every dimension)."""
    k = mi.UInt64(_u32(index)) * mi.UInt64(dims) + mi.UInt64(dim) + 1
    a, c = _lcg_jump(k)
    x0 = ((int(seed) & 0xFFFFFFFF) << 16) | 0x330E
    state = (a * x0 + c) & _LCG_MASK
    return dr.minimum(mi.Float(mi.Float64(state) * (1.0 / float(1 << 48))), 1.0 - 2.0 ** -24)


def independent_dynamic(index, dim, seed=0):
    """PCG32 stream per point, one generator state per dimension (JIT ``dim``)."""
    index = _u32(index)
    state = mi.UInt64(hash_u32(mi.UInt32(dim), int(_hash(seed, 0x1D)))) | (mi.UInt64(index) << 32)
    rng = mi.PCG32(dr.width(index), state, mi.UInt64(index))
    return rng.next_float32()


def sample_dynamic(sequence, index, dim, dims, scramble=False, seed=0):
    """Coordinate ``dim`` (a Python int turned into an opaque JIT value, so that all
    dimensions share one compiled kernel) of points ``index`` of ``sequence``.
    Randomisation as in :func:`sample`: Owen scrambling (Sobol), random digit
    permutations (Halton), a Cranley-Patterson rotation on top of Faure's permutations,
    seeds for lcg / independent."""
    if not 0 <= int(dim) < max_dim(sequence):
        raise DimensionError("%s: dim=%r is outside the supported dimensions [0, %d)"
                             % (sequence, dim, max_dim(sequence)))
    d = dr.opaque(mi.UInt32, int(dim))
    if sequence == "sobol":
        owen = hash_u32(d, dr.opaque(mi.UInt32, _hash(seed, 0x5EED))) if scramble else None
        return sobol_dynamic(index, d, owen)
    if sequence == "halton":
        return halton_dynamic(index, d, permutation_seed=int(seed) if scramble else None)
    if sequence == "faure":
        x = halton_dynamic(index, d, faure=True)
        if not scramble:
            return x
        y = x + _hashed_unit(d, dr.opaque(mi.UInt32, _hash(seed, 0xFA)))
        return dr.select(y >= 1.0, y - 1.0, y)
    if sequence == "lcg":
        return lcg_dynamic(index, dr.opaque(mi.UInt64, int(dim)), dr.opaque(mi.UInt64, int(dims)), seed)
    if sequence == "independent":
        return independent_dynamic(index, d, seed)
    raise ValueError("sequence=%r: must be one of %s" % (sequence, ", ".join(SEQUENCES)))
