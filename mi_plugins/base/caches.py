"""The package's caches of the last scene it rendered, and :func:`release`, which drops
them all.

Between renders the package keeps the last scene's patch table, its refined and
dark-split tables and ``ray_bundle``'s recorded steps, so that the next view of the same
scene starts at once. They hold that scene, and so its plugins, alive after the caller
drops it. Dr.Jit traces the methods of every live plugin in every later vcall (of any
integrator, Mitsuba's too): later kernels grow, and one of an old scene's plugins that
a later integrator's vcall cannot trace makes that render fail (a checkerboard-textured
area light kept alive makes Mitsuba's ``ptracer`` raise ``Texture::sample_spectrum(): not
implemented`` on another scene). :func:`release` (``mi_plugins.release()``) frees them.
"""
import gc

#: the functions that empty one cache each (registered by the modules that own them)
_CLEARERS = []


def register(clear):
    """Add ``clear`` (no arguments: empties one cache) to what :func:`release` calls;
    returns ``clear``."""
    _CLEARERS.append(clear)
    return clear


def release():
    """Empty every registered cache, then collect the garbage: a scene the caller no longer
    holds is freed, with its plugins."""
    for clear in _CLEARERS:
        clear()
    gc.collect()
