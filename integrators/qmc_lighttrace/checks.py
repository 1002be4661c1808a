"""The limits of ``qmc_lighttrace``'s work (what it refuses is in ``check_scene``: shapes
without patches and one-direction emitters, :mod:`mi_plugins.base.errors`).

The limits: paths and gather samples by the parameter reader, eye rays x gather samples
by :func:`check_gather_lanes`, deposit layers x patches by ``qmc_store.check_memory``,
each against a documented maximum and the available memory.
"""
from mi_plugins.base.params import parameter_error

#: bytes per gather lane of a render (its numbers, state and result)
BYTES_PER_GATHER_LANE = 64


def check_gather_lanes(plugin, frame, gather_samples):
    """Refuse before any work (a Params-style error naming gather_samples) when the eye
    rays x gather samples of one render reach 2^32 lanes, or when one pass of a camera
    sample per pixel needs more than half the available memory. Returns the passes:
    (camera samples per pixel and pass, passes), at most ``display.MAX_PASS_LANES``
    gather lanes a pass where the samples per pixel allow it."""
    from mi_plugins.base.limits import available_memory
    from mi_plugins.solution.display import pass_layout
    sr, pixels = int(gather_samples), frame.sample_pixels()
    lanes, available = pixels * frame.spp * sr, available_memory()
    if lanes >= 1 << 32 or (available is not None and pixels * sr * BYTES_PER_GATHER_LANE > available // 2):
        raise parameter_error(plugin, [("gather_samples", gather_samples)], (
            "a count whose %d eye rays x gather samples (%d lanes here) stay below 2^32 lanes, and whose "
            "lanes of one camera sample per pixel (%d bytes each) fit in half the available memory; use fewer "
            "gather_samples or samples per pixel" % (lanes // sr, lanes, BYTES_PER_GATHER_LANE)))
    return pass_layout(frame.spp, pixels * sr)
