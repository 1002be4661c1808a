"""Sizes a user can ask for, checked before any work: lanes (Dr.Jit's 32-bit indices)
and memory (Linux' MemAvailable). A request beyond them raises a ``ValueError`` /
``MemoryError`` naming the plugin, the parameters and the largest value that fits, instead
of a hang, an allocation failure or a process killed by the system."""
import os

#: the most lanes of one Dr.Jit array (indices are 32-bit)
MAX_LANES = (1 << 32) - 1
#: a request may use at most this share of the available memory
MEMORY_SHARE = 0.5


def available_memory():
    """Bytes of memory available (Linux' MemAvailable, else the free physical pages), or
    None where it is not known."""
    try:
        with open("/proc/meminfo") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    except (OSError, StopIteration, ValueError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_lanes(plugin, what, lanes, bytes_per_lane, per_unit, unit):
    """Refuse ``lanes`` (``what``: how they come about, e.g. "spp=64 x 128 x 128 pixels")
    beyond 2^32 - 1 or beyond ``MEMORY_SHARE`` of the available memory at
    ``bytes_per_lane``; ``per_unit`` lanes per unit of the parameter ``unit`` name the
    largest value that fits."""
    limit = MAX_LANES
    available = available_memory()
    if available is not None:
        limit = min(limit, int(available * MEMORY_SHARE // bytes_per_lane))
    if lanes > limit:
        need = lanes * bytes_per_lane / 1e9
        raise MemoryError("%s: %s = %d lanes (about %.3g GB) exceed what this machine holds at once (%d lanes: "
                          "2^32 - 1, and %d %% of the %.3g GB available); valid range: %s <= %d (render more "
                          "passes instead, e.g. `mi-plugins render --passes`)"
                          % (plugin, what, lanes, need, limit, 100 * MEMORY_SHARE,
                             (available or 0) / 1e9, unit, max(limit // max(per_unit, 1), 0)))
