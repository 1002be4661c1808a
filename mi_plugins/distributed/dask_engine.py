"""Running the tasks of :mod:`.plan` on a Dask cluster (``dask.distributed``).

:func:`run_tasks` submits one task per :class:`~.plan.Task` (``pure=False``: a rerun is a
new computation, never a cached result), collects the results as they complete (a
progress bar over all tasks), and returns them by task index, so the merge order never
depends on which worker finished first. A worker lost mid-render is Dask's to handle: its
tasks are rerun elsewhere, and as a task's result depends only on the task, the image is
unchanged. The scene and a first phase's result reach the workers as :class:`Shipped`
data: where every worker that held them is lost (a one-worker cluster whose worker
died), the scheduler cancels the tasks that need them; the data is scattered again from
this process's copy and the tasks are submitted again. A task whose future the scheduler
cancels on its own (a key it forgot) is submitted again (``RESUBMITS`` times at most).
A task that raises stops the render: the other tasks are cancelled and the task's
exception is raised, with the task named. Ctrl-C cancels the outstanding tasks and
returns what finished (``interrupted``).
"""
import uuid


def set_variant_on(client, variant):
    """Make every worker of ``client`` (and every worker that joins later) use Mitsuba
    ``variant`` before it unpickles a task: unpickling imports this package, which needs a
    variant set. A Dask worker plugin does it, whatever environment the cluster's workers
    were started with (a user's own ``LocalCluster`` or a remote cluster). Its class is
    made here, so that it is pickled by value: a worker need not import this package to
    receive it."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class MitsubaVariant(WorkerPlugin):
        name = "mi-plugins-variant"

        def __init__(self, variant):
            self.variant = variant

        def setup(self, worker):
            import os
            os.environ["MI_PLUGINS_VARIANT"] = self.variant
            import mitsuba as mi
            if mi.variant() != self.variant:
                mi.set_variant(self.variant)

    client.register_plugin(MitsubaVariant(variant))


class TaskFailed(RuntimeError):
    """A task raised: ``task`` and ``error`` (the original exception, also the cause)."""

    def __init__(self, task, total, error):
        super().__init__("distributed render: %s failed: %s: %s" % (task.describe(total), type(error).__name__, error))
        self.task, self.error = task, error


def _bar(total, desc, show):
    if not show:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, desc=desc, unit="task")


class Shipped:
    """``data`` scattered to every worker of ``client`` (own key: never a released twin);
    :meth:`future` scatters it again where the workers holding it were lost."""

    def __init__(self, client, data):
        self.client, self.data, self._future = client, data, None

    def future(self):
        if self._future is None or self._future.status != "finished":
            # (in a list: a tuple or a list would be scattered item by item)
            self._future = self.client.scatter([self.data], broadcast=True, hash=False)[0]
        return self._future


def _resolved(values):
    """``values`` with every :class:`Shipped` replaced by its current future."""
    return tuple(v.future() if isinstance(v, Shipped) else v for v in values)


#: a task whose future the scheduler cancels (not this client: a key it forgot, e.g. after a
#: lost connection, or its shipped data lost with the workers that held it) is submitted
#: again, this many times at most
RESUBMITS = 2


def run_tasks(client, fn, tasks, args, progress=True, desc="tasks"):
    """Run ``fn(*args[0], task, *args[1:])`` for every task on ``client`` (a
    :class:`Shipped` value in ``args[0]`` or ``args[1:]`` is passed as its future): returns
    (results: index -> value, interrupted)."""
    from distributed import as_completed
    from distributed.client import FutureCancelledError
    tag = uuid.uuid4().hex[:8]
    head, tail = args[0], tuple(args[1:])

    def submit(task, attempt=0):
        key = "mi-plugins-%s-%s-%d" % (tag, task.kind, task.index) + ("-again%d" % attempt if attempt else "")
        return client.submit(fn, *_resolved(head), task, *_resolved(tail), key=key, pure=False)

    futures = {submit(task): task for task in tasks}
    results, bar, again = {}, _bar(len(tasks), desc, progress), {}
    # on this client's event loop: by default Dask tracks the futures on its default
    # client's loop (the newest client), and a future waited for again there, after a
    # gather that found its data lost, fails as bound to a different event loop
    running = as_completed(list(futures), loop=client.loop)
    try:
        for future in running:
            task = futures.pop(future)
            if future.status == "error":
                error = future.exception()
                raise TaskFailed(task, len(tasks), error) from error
            try:
                results[task.index] = future.result()
            except FutureCancelledError as error:
                again[task.index] = again.get(task.index, 0) + 1
                if again[task.index] > RESUBMITS:
                    raise TaskFailed(task, len(tasks), error) from error
                retry = submit(task, again[task.index])
                futures[retry] = task
                running.add(retry)
                continue
            if bar is not None:
                bar.update(1)
    except KeyboardInterrupt:
        client.cancel([f for f in futures if not f.done()])
        return results, True
    except BaseException:
        client.cancel(list(futures))
        raise
    finally:
        if bar is not None:
            bar.close()
    return results, False
