"""Named random streams: every seed of the package's integrators comes from here.

A render seed (``mi.render(..., seed=s)``) is expanded into independent streams, one
per purpose, by hashing (seed, stream, index): :func:`stream` gives the 32-bit seed of
a stream, :func:`pcg` a ``mi.PCG32`` with one lane per element seeded from it (the
seed is an opaque JIT value, so a new seed reuses the compiled kernels), and
:func:`numpy_rng` a numpy Generator for scalar set-up (e.g. global directions). The
stream names are listed in ``STREAMS``; two purposes never share a stream.
"""
import drjit as dr
import mitsuba as mi
import numpy as np

#: every stream the package uses (name -> tag mixed into the hash)
STREAMS = {
    "camera": 1,        # sensor samplers of the integrators' camera passes
    "camera_path": 2,   # decisions along camera paths (specular chains, light samples)
    "light": 3,         # light paths of stochastic_ray
    "power": 4,         # stochastic_ray's estimate of the emitted power
    "lines": 5,         # ray_bundle's line jitter
    "patches": 6,       # ray_bundle's points on patches
    "directions": 7,    # ray_bundle's global directions
    "gather": 8,        # ray_bundle's final gathering
    "particles": 9,     # qmc_lighttrace's sequence randomisation
    "direct": 10,       # ray_bundle's shared direct light of diffuse patches
    "tasks": 11,        # render seeds of the chain tasks of a distributed ray_bundle render
    "solution": 12,     # the direct light of the patches of a view-independent solution
    "display": 13,      # camera paths of the display modes of a solution
    "refine": 14,       # ray_bundle's measurement of the direct light in the children of patches
    "gather pass": 15,  # render seeds of qmc_lighttrace's camera passes after the first
    "steep": 16,        # the second solve that decides a smooth display's steep patches
    "residual": 17,     # the display's camera samples that also gather (its residual check)
}


from mi_plugins.base.sequences import hash32  # noqa: E402  (the package's one hash, ints or mi.UInt32 arrays)


def stream(seed, name, index=0):
    """The 32-bit seed of stream ``name`` (one of ``STREAMS``), number ``index``, of the
    render seed ``seed``."""
    if name not in STREAMS:
        raise KeyError("unknown random stream %r; streams: %s" % (name, ", ".join(STREAMS)))
    return hash32(seed, STREAMS[name], index)


def pcg(size, seed, name, index=0):
    """A ``mi.PCG32`` of ``size`` lanes (lane = sequence) on stream ``name``."""
    state = dr.opaque(mi.UInt64, stream(seed, name, index))
    return mi.PCG32(size, initstate=state, initseq=mi.UInt64(dr.arange(mi.UInt32, size)))


def numpy_rng(seed, name, index=0):
    """A numpy Generator on stream ``name`` (for scalar set-up)."""
    return np.random.default_rng([stream(seed, name, index), STREAMS[name]])
