"""numpy and Dr.Jit array helpers that setup code needs on a million triangles.

:func:`distinct`: the sorted distinct values of an integer array by one sort (numpy 2.4's
``np.unique(x)`` without further outputs takes a hash path about 50 times slower on
millions of keys). :func:`jit`: a Dr.Jit array of numpy columns in memory aligned to 64
bytes: Dr.Jit reads numpy memory in place and compiles its kernels for the alignment it
finds (a vector load of ``align 64`` or of ``align 1``), so arrays made from numpy at
whatever address the allocator gave would compile the same kernel anew for every new
scene object (each variant a fresh compilation, 0.1-1 s for the large kernels)."""
import drjit as dr
import numpy as np

#: numpy dtype of each Dr.Jit scalar type
_DTYPES = {dr.VarType.Float32: np.float32, dr.VarType.Float64: np.float64, dr.VarType.UInt32: np.uint32,
           dr.VarType.Int32: np.int32, dr.VarType.UInt64: np.uint64, dr.VarType.Int64: np.int64,
           dr.VarType.Bool: np.bool_}

ALIGN = 64


def distinct(values):
    """The sorted distinct values of a 1-D array (``np.unique(values)``)."""
    values = np.sort(np.asarray(values).ravel())
    if len(values) < 2:
        return values
    keep = np.empty(len(values), dtype=bool)
    keep[0] = True
    np.not_equal(values[1:], values[:-1], out=keep[1:])
    return values[keep]


def aligned(values, dtype):
    """A copy of ``values`` as ``dtype``, C-contiguous, starting at a 64-byte boundary."""
    values = np.asarray(values, dtype=dtype)
    raw = np.empty(values.nbytes + ALIGN, dtype=np.uint8)
    start = (-raw.ctypes.data) % ALIGN
    out = raw[start:start + values.nbytes].view(dtype).reshape(values.shape)
    out[...] = values
    return out


def jit(kind, *columns):
    """``kind(*columns)`` (a Dr.Jit type: ``mi.Float``, ``mi.UInt32``, ``mi.Point3f``, ...)
    with every numpy column first copied to aligned memory of ``kind``'s scalar type
    (other arguments, Python numbers or Dr.Jit arrays, are passed as they are)."""
    dtype = _DTYPES[dr.type_v(kind)]
    return kind(*(aligned(c, dtype) if isinstance(c, np.ndarray) and c.ndim else c for c in columns))


def row_keys(rows):
    """One int64 per row of the 2-D integer array ``rows``, equal where the rows are equal
    and ordered as the rows are lexicographically (each column's rank in a mixed radix),
    so ``np.unique(row_keys(rows), ...)`` does what ``np.unique(rows, axis=0, ...)`` does
    at the speed of 1-D keys; None where the ranks do not fit in 63 bits."""
    rows = np.asarray(rows)
    key = np.zeros(len(rows), dtype=np.int64)
    span = 1
    for column in rows.T:
        values, rank = np.unique(column, return_inverse=True)
        span *= max(len(values), 1)
        if span >= 2 ** 62:
            return None
        key = key * len(values) + rank.ravel()
    return key
