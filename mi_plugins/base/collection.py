"""When Python's garbage collector runs around the package's renders.

Dr.Jit traces a call through a Mitsuba plugin pointer (a BSDF, an emitter, a shape, ...)
for every live instance of the plugin's kind. An instance freed while such a call is
traced, by a collection that the tracing itself sets off or that another thread runs
meanwhile (a Dask worker's event loop: Mitsuba's C++ integrators release the GIL while
they trace), is used after it was freed: a crash, or Dr.Jit's "jit_registry_id(...):
pointer is not registered". An earlier scene's plugins are freed by a collection where
something of the package held them in a reference cycle. So:

- the package's code makes no reference cycles that hold a render's objects (a test
  renders with every integrator and display and finds none);
- its renders pause the collector (:func:`paused`): nothing is freed by a collection
  while they trace, in any thread;
- a distributed worker runs every task so paused and collects at its end, in the task's
  own thread, where nothing is traced (:func:`task`), one task at a time per process
  (:mod:`mi_plugins.distributed.serial`): the collector's switch belongs to the process,
  and a task ending beside another would turn it on while the other traces.
"""
import contextlib
import gc


@contextlib.contextmanager
def paused():
    """The collector off within the block (for every thread; nested blocks keep it off
    until the outermost ends); on again after it if it was on."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()


@contextlib.contextmanager
def task():
    """A worker's task: :func:`paused`, then a collection in this thread at its end, so
    that what the task left (an earlier scene, a render's state) is freed here and now."""
    try:
        with paused():
            yield
    finally:
        gc.collect()
