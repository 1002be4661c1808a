"""The limits of ``qmc_lighttrace``'s work (what it refuses is in ``check_scene``: shapes
without patches and one-direction emitters, :mod:`mi_plugins.support`).

The limits: paths and gather samples by the parameter reader, eye rays x gather samples
by :func:`check_gather_lanes`, deposit layers x patches by ``qmc_store.check_memory``,
each against a documented maximum and the available memory.
"""
from mi_plugins.params import parameter_error

#: bytes per gather lane of a render (its numbers, state and result)
BYTES_PER_GATHER_LANE = 64


def check_gather_lanes(plugin, frame, gather_samples):
    """Refuse before any work (a Params-style error naming gather_samples) when the eye
    rays x gather samples of one render exceed 2^32 lanes or half the available memory."""
    from mi_plugins.limits import available_memory
    film = frame.film
    border = film.rfilter().border_size() if film.sample_border() else 0
    lanes = (frame.width + 2 * border) * (frame.height + 2 * border) * frame.spp * int(gather_samples)
    available = available_memory()
    if lanes >= 1 << 32 or (available is not None and lanes * BYTES_PER_GATHER_LANE > available // 2):
        raise parameter_error(plugin, [("gather_samples", gather_samples)], (
            "a count whose %d eye rays x gather samples (%d lanes here) stay below 2^32 lanes and half the "
            "available memory (%d bytes per lane); use fewer gather_samples or samples per pixel, or render in "
            "passes" % (lanes // int(gather_samples), lanes, BYTES_PER_GATHER_LANE)))
