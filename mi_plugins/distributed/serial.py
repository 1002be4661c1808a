"""One task at a time in a worker process, whatever its number of Dask threads.

Dr.Jit's recording state (loops, calls through plugin pointers, frozen functions) and
the collector switch of :mod:`mi_plugins.base.collection` belong to the process: two tasks
tracing at once in two threads of one worker corrupt each other (a loop variable
"presumed to be constant, but it changed", an unknown variable, a hang). So every task
body takes :data:`LOCK` first (:func:`task`): a worker with N Dask threads runs its
Mitsuba work one task at a time, and each task still uses every core through Dr.Jit's
own thread pool. The lock is re-entrant (a task body may call another worker function);
it is released whatever ends the body (a return, an exception, an interrupt). A task
cancelled while it waits for the lock (Ctrl-C on the client, another task failed) does
not run: it raises :class:`Abandoned`, which Dask drops.

:func:`stats` counts, per process, the task bodies that ran, the most that overlapped
and those that had to wait: the overlap detector of the tests.
"""
import contextlib
import threading

from mi_plugins.base import collection

#: held by the task body running in this process (re-entrant)
LOCK = threading.RLock()

#: seconds between two looks at whether a waiting task was cancelled
POLL = 0.05

_count = threading.Lock()
_inside = {}                               # thread id -> depth of the bodies it runs
_stats = {"tasks": 0, "peak": 0, "waited": 0}


class Abandoned(RuntimeError):
    """The task was cancelled while it waited for this worker's running task."""


def _cancelled():
    """True when this thread runs a Dask task that the scheduler cancelled (False outside
    a Dask worker, or where Dask's worker state cannot be read)."""
    try:
        from distributed import get_worker
        worker = get_worker()
        state = worker.state.tasks.get(worker.get_current_task())
        return state is not None and state.state == "cancelled"
    except Exception:
        return False


def _acquire():
    if LOCK.acquire(blocking=False):
        return
    with _count:
        _stats["waited"] += 1
    while not LOCK.acquire(timeout=POLL):
        if _cancelled():
            raise Abandoned("the task was cancelled while it waited for this worker's running task")


@contextlib.contextmanager
def _counted():
    me = threading.get_ident()
    with _count:
        _inside[me] = _inside.get(me, 0) + 1
        if _inside[me] == 1:
            _stats["tasks"] += 1
            _stats["peak"] = max(_stats["peak"], len(_inside))
    try:
        yield
    finally:
        with _count:
            _inside[me] -= 1
            if not _inside[me]:
                del _inside[me]


@contextlib.contextmanager
def task():
    """A task body: :data:`LOCK` held, then :func:`mi_plugins.base.collection.task` (the
    collector paused, a collection at the end, both inside the lock: no other task of the
    process traces meanwhile)."""
    _acquire()
    try:
        with _counted(), collection.task():
            yield
    finally:
        LOCK.release()


def stats(reset=False):
    """{'tasks': bodies run, 'peak': most bodies running at once (in distinct threads),
    'waited': bodies that found the lock taken} in this process; zeroed after if ``reset``."""
    with _count:
        out = dict(_stats)
        if reset:
            _stats.update(tasks=0, peak=0, waited=0)
    return out
