"""Frozen steps of ``ray_bundle`` (``dr.freeze``): each kind of step (a burn-in
iteration, an averaged iteration, a final-gathering pass) is traced once per render and
its kernels are replayed afterwards.

Tracing an iteration in Python costs far more than running it on small scenes: the
vcalls over every BSDF and emitter of the scene are re-traced at every step (0.16 s per
iteration for the direct light of a scene with seven emitters, 5 ms replayed). A frozen
step must see every Dr.Jit value it reads among its inputs: :func:`jit_leaves` collects
them from the helper objects the step uses (the patch table, the transport, the
averages, the film's blocks, the scene); everything that changes from step to step is a
Dr.Jit value (directions, seeds, random states), never a Python number, so a replay
never reuses a stale value.
"""
import dataclasses
import gc
from collections import OrderedDict

import drjit as dr
import mitsuba as mi
import numpy as np

#: freeze the steps (tests switch it off to see the tracing of every iteration)
ENABLED = True


def jit_leaves(*objects):
    """Every Dr.Jit array, Dr.Jit struct (e.g. ``mi.PCG32``), dataclass and Mitsuba
    object reachable from ``objects`` through attributes, lists, tuples and dicts (depth
    first, in order). A loop over a stack, not a recursive local function: such a function
    is a reference cycle (it holds itself through its closure) that keeps what it found,
    the scene's plugins among them, alive until the garbage collector runs, which may be
    in another thread while a later render traces the same kind of plugin."""
    out, seen, stack = [], set(), list(reversed(objects))
    while stack:
        obj = stack.pop()
        if obj is None or isinstance(obj, (bool, int, float, str, np.ndarray, type)) or id(obj) in seen \
                or (dr.is_array_v(obj) and not dr.is_jit_v(obj)):
            continue
        seen.add(id(obj))
        if dr.is_jit_v(obj) or isinstance(obj, mi.Object) or hasattr(type(obj), "DRJIT_STRUCT") \
                or dataclasses.is_dataclass(obj):
            out.append(obj)
        elif isinstance(obj, (list, tuple)):
            stack.extend(reversed(obj))
        elif isinstance(obj, dict):
            stack.extend(reversed(list(obj.values())))
        elif hasattr(obj, "__dict__"):
            stack.extend(reversed(list(vars(obj).values())))
    return out


def _aligned(x):
    """True if ``x`` is evaluated in memory aligned as Dr.Jit aligns its own (64 bytes):
    a frozen step replays on it as on a copy (e.g. the copy an earlier render made)."""
    if dr.depth_v(x) > 1:
        return all(_aligned(x[i]) for i in range(len(x)))
    return x.state == dr.VarState.Evaluated and x.numpy().ctypes.data % 64 == 0


def _owned(x):
    """``x`` itself if it is already in aligned memory of Dr.Jit's own (:func:`_aligned`),
    else a copy there: a gather by an opaque index, or for one element the sum with an
    opaque zero (``dr.copy``, ``x * 1``, a gather by a plain ``arange`` or from a single
    element keep an array mapped from numpy as it is)."""
    if dr.width(x) > 1 and _aligned(x):
        return x
    if dr.width(x) == 1:
        zero = dr.zeros(type(x), 1)
        dr.make_opaque(zero)
        return x | zero if dr.type_v(x) == dr.VarType.Bool else x + zero
    index = dr.arange(mi.UInt32, dr.width(x))
    dr.make_opaque(index)
    return dr.gather(type(x), x, index)


def own_arrays(*objects):
    """Replace every Dr.Jit array held by ``objects`` (plain Python objects: attributes,
    lists, tuples) by a copy in memory of Dr.Jit's own, evaluated. Arrays made from numpy
    can keep numpy's memory; a frozen step compiles its loads for the alignment of the
    memory it recorded (1 or 64 bytes), and numpy's alignment varies from render to
    render: without the copies, every render compiled its steps anew (0.5 s each). Arrays
    that a previous render made Dr.Jit's own are kept (copying a 1 M-triangle scene's patch
    table again took 0.34 s a render)."""
    seen, made = set(), []
    for obj in objects:
        _own_in(obj, seen, made)
    dr.eval(made)


def _own_in(value, seen, made):
    """``value`` with its Dr.Jit arrays owned (:func:`own_arrays`; new ones added to
    ``made``; objects in ``seen`` done). A module function, not a local one: see
    :func:`jit_leaves`."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if dr.is_jit_v(value) and dr.width(value) > 0:
        value = _owned(value)
        made.append(value)
        return value
    if isinstance(value, list):
        value[:] = [_own_in(v, seen, made) for v in value]
    elif isinstance(value, tuple) and not hasattr(type(value), "_fields"):
        return tuple(_own_in(v, seen, made) for v in value)
    elif hasattr(value, "__dict__") and not isinstance(value, (mi.Object, type)) \
            and not dataclasses.is_dataclass(value) and not hasattr(type(value), "DRJIT_STRUCT") \
            and id(value) not in seen:
        seen.add(id(value))
        for key, item in list(vars(value).items()):
            setattr(value, key, _own_in(item, seen, made))
    return value


class FreezeFailed(RuntimeError):
    """A step could not be recorded; the render is to run again without frozen steps."""


class FrozenStep:
    """The method ``name`` of an *owner* frozen. The owner (a render's state) is hashed by
    its ``key``: every Python value its steps read (sizes, flags, the bounding sphere,
    the scene's fingerprint), so that a later render with an equal key replays the
    recorded kernels with its own arrays (``owner.leaves``: every Dr.Jit value the step
    reads, further inputs). Python arguments (flags) select a recording; Dr.Jit arguments
    are traversed. ``enabled=False``: plain calls."""

    def __init__(self, name, enabled=True):
        self.name = name

        def call(leaves, owner, args):
            return getattr(owner, name)(*args)
        # auto_opaque=False: every input is opaque (else each width-1 input whose value changes,
        # a seed, a counter, costs one more recording before it is made opaque)
        self.frozen = dr.freeze(call, warn_after=8, auto_opaque=False) if enabled and ENABLED else None

    def __call__(self, owner, *args):
        if self.frozen is None:
            return getattr(owner, self.name)(*args)
        before = self.frozen.n_recordings
        try:
            return self.frozen(owner.leaves, owner, args)
        except RuntimeError as error:
            if self.frozen.n_recordings == before:
                raise
            # Dr.Jit cannot record this step (e.g. a Python plugin calling another plugin
            # through a nested virtual call): the render starts over without freezing
            causes, cause = [str(error)], error.__cause__ or error.__context__
            while cause is not None and len(causes) < 4:
                causes.append(str(cause))
                cause = cause.__cause__ or cause.__context__
            raise FreezeFailed(" <- ".join(causes)) from error

    @property
    def recordings(self):
        return self.frozen.n_recordings if self.frozen is not None else 0


class StepCache:
    """An integrator's frozen steps (advance, image) per render key (see run.Run._key): a
    later render of the same scene and settings replays the kernels recorded by the
    first; the last ``size`` keys are kept. Keys whose steps could not be recorded
    (:class:`FreezeFailed`) get plain steps."""

    def __init__(self, size):
        self.size, self.steps, self.unfrozen, self.last = int(size), OrderedDict(), set(), None
        self.errors = {}            # key -> why its steps could not be recorded

    def clear(self):
        """Forget every recording (:func:`mi_plugins.base.caches.release`)."""
        self.steps.clear()
        self.unfrozen.clear()
        self.errors.clear()
        self.last = None

    def get(self, key, enabled):
        self.last = key
        enabled = bool(enabled and ENABLED and key not in self.unfrozen)
        key = key + (enabled,)
        if key not in self.steps:
            self.steps[key] = (FrozenStep("_advance", enabled), FrozenStep("_image", enabled))
            evicted = len(self.steps) > self.size
            while len(self.steps) > self.size:
                self.steps.popitem(last=False)
            if evicted:     # free the evicted recordings' scenes before this one's steps record: a
                gc.collect()    # plugin of theirs alive would be a call target outside the new steps' inputs
        self.steps.move_to_end(key)
        return self.steps[key]

    def failed(self, error=None):
        """The last key's steps could not be recorded (``error``: Dr.Jit's message, kept in
        ``errors``): plain steps from now on."""
        self.unfrozen.add(self.last)
        self.errors[self.last] = str(error)


def fingerprint(scene):
    """The scene's parameters that are not Dr.Jit arrays (Python numbers, strings, scalar
    arrays): a frozen step bakes them into its kernels, so a change must not replay them."""
    params = mi.traverse(scene)
    items = []
    for key in params.keys():
        try:
            value = params[key]
        except TypeError:
            continue
        if value is None or not dr.is_jit_v(value):
            items.append((key, str(value)))
    return tuple(items)


def freezable(scene, sensor):
    """False where a step that draws from the camera sampler cannot be frozen: the
    sensor's sampler is a Python plugin (its state lives in Python members that a replay
    would not advance)."""
    sampler = sensor.sampler()
    return type(sampler).__module__.split(".", 1)[0] == "mitsuba"
