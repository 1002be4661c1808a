"""Long ``path`` renders as references, cached on disk, and the errors of images against them.

A reference is rendered in chunks of independent seeds and kept as two halves, so that
its own noise can be taken out of an error: for independent halves a and b,
E[(a - b)^2] / 4 is the per-pixel variance of their mean. References are cached under the
temp dir (``CACHE``), one file per key of everything that sets the images (the scene's
dict, the views, the samples, Mitsuba's version): computed once, read by later runs.
"""
import hashlib
import os
import tempfile
import time

import mitsuba as mi
import numpy as np

#: where the references are kept (the temp dir: a cleaned temp dir renders them again)
CACHE = os.path.join(tempfile.gettempdir(), "mi_plugins_references")
#: the most samples one chunk of a reference traces (memory of one render)
CHUNK_SAMPLES = 1 << 22


class Reference:
    """A reference image: ``image`` (H, W, 3), ``variance`` (H, W, 3: the per-pixel
    variance of its own noise), ``mean`` (of ``image``) and ``away`` (the pixels away from
    any visible lamp: :func:`away_from_light`)."""

    def __init__(self, halves):
        halves = np.asarray(halves, dtype=np.float64)
        self.image = halves.mean(axis=0)
        self.variance = (halves[0] - halves[1]) ** 2 / 4.0
        self.mean = max(float(self.image.mean()), 1e-12)
        self.away = away_from_light(self.image)

    def errors(self, image):
        """(RMSE on the whole image, RMSE on the pixels away from the lamp) of ``image``
        relative to the reference's mean, the reference's own noise taken out (0 where
        the difference is within it)."""
        e = (np.asarray(image, dtype=np.float64)[..., :3] - self.image) ** 2
        full = np.sqrt(max(e.mean() - self.variance.mean(), 0.0)) / self.mean
        away = np.sqrt(max(e[self.away].mean() - self.variance[self.away].mean(), 0.0)) / self.mean \
            if self.away.any() else full
        return float(full), float(away)


def away_from_light(reference):
    """Pixels none of whose 3 x 3 neighbours sees the lamp (reference above 1 in a channel:
    the Cornell box's lamp emits 18.4, its brightest lit wall pixels stay below 0.5)."""
    lit = np.pad(np.asarray(reference)[..., :3].max(axis=-1) > 1.0, 1)
    h, w = reference.shape[:2]
    return ~np.any([lit[i:i + h, j:j + w] for i in range(3) for j in range(3)], axis=0)


def cache_file(tag, *key, cache=None):
    """The cache file of reference ``tag`` for the settings ``key`` (any values with a
    stable ``repr``; Mitsuba's version is added)."""
    digest = hashlib.sha1(repr((mi.MI_VERSION,) + key).encode()).hexdigest()[:16]
    return os.path.join(cache or CACHE, "%s_%s.npy" % (tag, digest))


def transform_key(transform):
    """A stable key of a ``to_world`` transform (its matrix, rounded to 1e-6)."""
    return tuple(np.round(np.array(transform.matrix, dtype=np.float64).ravel(), 6).tolist())


def path_references(scene_dict, spp, transforms=None, tag="reference", seed=1_000_000, cache=None, out=None):
    """The references (:class:`Reference`) of ``mi.load_dict(scene_dict)`` seen by its
    sensor moved along ``transforms`` (None: its own view, one reference), each Mitsuba's
    ``path`` at ``spp`` samples per pixel (rounded to an even number of chunks), read from
    the cache or rendered and cached; ``out(text)`` hears how long a rendering took."""
    res = scene_dict["sensor"]["film"]
    views = [None] if transforms is None else list(transforms)
    key = (repr(scene_dict), int(spp), [None if t is None else transform_key(t) for t in views])
    path = cache_file(tag, *key, cache=cache)
    if os.path.exists(path):
        return [Reference(halves) for halves in np.load(path)]
    t0 = time.perf_counter()
    scene, integrator = mi.load_dict(scene_dict), mi.load_dict({"type": "path"})
    chunk = max(1, min(int(spp) // 2, CHUNK_SAMPLES // (int(res["width"]) * int(res["height"]))))
    chunks = max(2, 2 * (int(spp) // (2 * chunk)))
    from mi_plugins.solution.views import render_camera_path
    stacks = []
    for k, transform in enumerate(views):
        images = []
        for c in range(chunks):
            s = seed + k * chunks + c
            image = (mi.render(scene, integrator=integrator, spp=chunk, seed=s) if transform is None
                     else render_camera_path(scene, integrator, [transform], spp=chunk, seed=s)[0])
            images.append(np.array(image, dtype=np.float32)[..., :3])
        stacks.append([np.mean(images[0::2], axis=0), np.mean(images[1::2], axis=0)])
    stacks = np.asarray(stacks, dtype=np.float32)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    np.save(path + ".part.npy", stacks)
    os.replace(path + ".part.npy", path)
    if out is not None:
        out("  (%s: %d view%s of path at %d spp rendered in %.0f s, kept in %s)" % (
            tag, len(views), "" if len(views) == 1 else "s", chunks * chunk, time.perf_counter() - t0, path))
    return [Reference(halves) for halves in stacks]
