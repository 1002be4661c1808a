"""A content fingerprint of a Mitsuba scene: what a stored solution must match.

Each shape's digest hashes its class, triangle count and the value of every parameter
``mi.traverse(shape)`` exposes (vertex positions, faces, uv, transform, its BSDF and
area emitter: reflectances, texture data, radiances), read back from Dr.Jit; emitters
without a shape (environment and delta lights) get digests of their own. The scene's
fingerprint combines them as a set: Mitsuba's mesh merging orders merged shapes
differently from one load to the next, so two loads of the same file give the same
fingerprint, and a solution stored for one load finds its shapes in another by their
digests (:func:`shape_digests`). An edit through ``mi.traverse`` followed by
``update()`` changes it; sensors, films, samplers and integrators do not enter it (they
do not change the light).
"""
import contextlib
import hashlib
import re

import drjit as dr
import mitsuba as mi
import numpy as np

#: names Mitsuba makes up at load time (a merged mesh is 'object_<address>'): not content
GENERATED = re.compile(r"object_[0-9]+|_unnamed_[0-9]+")


def _name(text):
    return GENERATED.sub("object", text)


def _update(h, obj):
    """Hash every traversable parameter of the Mitsuba object ``obj``."""
    params = mi.traverse(obj)
    for key in params.keys():
        h.update(_name(key).encode())
        try:
            value = params[key]
        except TypeError:      # a parameter exposed without a value
            continue
        if value is None:
            continue
        if dr.is_array_v(value):
            flat = dr.ravel(value) if dr.depth_v(value) > 1 else value
            # a view of Dr.Jit's memory where it can be (no copy of a million triangles)
            data = np.ascontiguousarray(flat.numpy() if dr.is_jit_v(flat) else np.array(flat))
            h.update(str(data.dtype).encode())
            h.update(data)
        else:
            h.update(repr(value).encode())


def shape_summary(scene):
    """[(class name, triangle count or 0)] of every shape of ``scene``, in order."""
    return [(shape.class_name() if hasattr(shape, "class_name") else type(shape).__name__,
             int(shape.face_count()) if isinstance(shape, mi.Mesh) else 0) for shape in scene.shapes()]


def shape_digest(shape):
    """Hex digest of one shape (geometry, transform, BSDF, area emitter)."""
    h = hashlib.sha1()
    name = shape.class_name() if hasattr(shape, "class_name") else type(shape).__name__
    faces = int(shape.face_count()) if isinstance(shape, mi.Mesh) else 0
    h.update(("%s %d %s" % (name, faces, shape.has_flipped_normals())).encode())
    _update(h, shape)
    return h.hexdigest()


#: id(scene) -> {what: value} for the scenes inside :func:`held` (hashing a million
#: triangles takes 0.1 s, and one render asks for the digests up to four times)
_HELD = {}


@contextlib.contextmanager
def held(scene):
    """Within the block, ``scene``'s digests and fingerprint are computed once: for code
    that does not change the scene meanwhile (one render)."""
    key, outer = id(scene), id(scene) in _HELD
    _HELD.setdefault(key, {})
    try:
        yield
    finally:
        if not outer:
            _HELD.pop(key, None)


def _memo(scene, what, make):
    memo = _HELD.get(id(scene))
    if memo is None:
        return make()
    if what not in memo:
        memo[what] = make()
    return memo[what]


def shape_digests(scene):
    """The digest of every shape of ``scene``, in ``scene.shapes()`` order."""
    return list(_memo(scene, "shapes", lambda: [shape_digest(shape) for shape in scene.shapes()]))


def scene_fingerprint(scene):
    """A hex digest of ``scene``'s shapes and emitters, independent of their order."""
    return _memo(scene, "scene", lambda: _scene_fingerprint(scene))


def _scene_fingerprint(scene):
    parts = sorted(shape_digests(scene))
    for emitter in scene.emitters():
        if emitter.get_shape() is None:
            h = hashlib.sha1(emitter.class_name().encode())
            _update(h, emitter)
            parts.append("emitter " + h.hexdigest())
    return hashlib.sha1("\n".join(sorted(parts)).encode()).hexdigest()
