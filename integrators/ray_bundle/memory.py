"""Every size of a ``ray_bundle`` render, checked before any work.

A render's memory is, per iteration: the chains' lanes (chains x patch sides x orders),
the bundles' lines (``resolution``^2 x chains), the camera samples of one pass (pixels x
the chains of a camera group: a pass splits its chains into groups that fit) and the
patch table; the global directions are made a block at a time
(:class:`~mi_plugins.integrators.ray_bundle.directions.DirectionStream`), never all at
once. :func:`check` refuses a render that would need more memory than is available
(``MemoryError``, naming the chains that fit) or a size beyond the documented maxima
(``ValueError``), and warns above a quarter of the available memory. The byte counts are
measured peaks (``BYTES_PER_LANE``: 64 chains on 70 k triangles: 0.81 GB = 93 B per lane;
16 chains on 1 M triangles: 3.57 GB = 116 B).
"""
import warnings

import mitsuba as mi
import numpy as np

from mi_plugins.patches import tessellation
from mi_plugins.patches.mesh_parts import patch_count
from mi_plugins.base.queries import is_mesh, reflects_on_both_sides
from mi_plugins.patches.meshtable import require_meshes
from mi_plugins.base.limits import available_memory  # noqa: F401  (re-exported)

#: bytes per lane (chain x patch side) with one order, and per further order
BYTES_PER_LANE = 120
BYTES_PER_ORDER = 48
#: bytes per line of a bundle (the walk's loop state) and per camera sample of a pass
BYTES_PER_LINE = 128
BYTES_PER_CAMERA_SAMPLE = 512
#: bytes per patch of the patch table (with its construction's temporaries)
BYTES_PER_PATCH = 640
#: iterations of one render (iterations x spp) at the most
MAX_ITERATIONS = 1 << 20
#: lanes, lines and camera samples of a pass at the most (32-bit indices)
MAX_LANES = 1 << 31
#: finite max_depth at the most (each order is a full copy of the chains' radiance)
MAX_DEPTH = 64


def lane_bytes(orders=1):
    return BYTES_PER_LANE + BYTES_PER_ORDER * (int(orders) - 1)


def chain_bytes(patch_sides, resolution, orders=1):
    """Memory of one chain: its lanes and its bundle's lines."""
    return patch_sides * lane_bytes(orders) + int(resolution) ** 2 * BYTES_PER_LINE


def chains_that_fit(available, patch_sides, resolution=0, orders=1):
    return int(available // chain_bytes(patch_sides, resolution, orders))


def default_chains(chains, patch_sides, resolution, available, orders=1):
    """``chains``, or fewer (at least 1) where they would need over a quarter of
    ``available`` bytes (None: not known, ``chains``)."""
    if available is None:
        return int(chains)
    return max(1, min(int(chains), chains_that_fit(available / 4, patch_sides, resolution, orders)))


def predicted_patches(scene, h, subdivide, cluster=True):
    """Patch sides the table of ``scene`` will have (as MeshTable counts them), without
    building it: a tiny ``patch_size`` is refused before it allocates anything."""
    require_meshes(scene, "ray_bundle")
    total = 0
    for shape in scene.shapes():
        if is_mesh(shape):
            params = mi.traverse(shape)
            faces = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
            p = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)[faces]
            count = patch_count(p, h, subdivide, cluster)
        else:
            count = tessellation.ShapePatches(shape, h).count
        total += count * (2 if reflects_on_both_sides(shape) else 1)
    return total


def camera_group(chains, camera_lanes_per_chain, available):
    """Chains per camera pass: the largest divisor of ``chains`` whose camera samples fit
    a quarter of ``available`` (all of them where it is not known)."""
    if available is None:
        return int(chains)
    fit = max(1, int(available / 4 // (camera_lanes_per_chain * BYTES_PER_CAMERA_SAMPLE)))
    return max(d for d in range(1, int(chains) + 1) if chains % d == 0 and d <= fit)


def sampler_group(sampler, chains, group):
    """The largest divisor of ``chains`` up to ``group`` whose count of camera samples per
    pixel and pass ``sampler`` keeps ('stratified' and 'multijitter' round counts to
    squares, 'orthogonal' to squares of primes: with 16 chains it takes passes of 4);
    ``group`` where none is kept (the frame then refuses the sampler, naming it)."""
    for d in range(int(group), 0, -1):
        if chains % d == 0:
            probe = sampler.clone()
            probe.set_sample_count(d)
            if probe.sample_count() == d:
                return d
    return int(group)


def _refuse(text):
    raise ValueError("ray_bundle: " + text)


def check_sizes(iterations, spp, resolution, max_depth):
    """The documented maxima of the parameters and of ``spp`` (before the scene is read)."""
    total = int(iterations) * int(spp)
    if total > MAX_ITERATIONS:
        _refuse("spp=%d x iterations=%d = %d iterations exceed the maximum of %d per render (MAX_ITERATIONS: "
                "the global directions of one render); valid range here: spp <= %d; for more samples render "
                "several images with other seeds and average them" % (spp, iterations, total, MAX_ITERATIONS,
                                                                       max(MAX_ITERATIONS // int(iterations), 1)))
    if int(resolution) ** 2 >= MAX_LANES:
        _refuse("resolution=%d: resolution^2 lines per chain exceed 2^31; valid range: resolution <= 46340"
                % resolution)
    if max_depth > MAX_DEPTH:
        _refuse("max_depth=%d: a finite depth keeps every bounce order apart (a copy of the chains' radiance "
                "each); valid range: -1 (unbounded) or 0 .. %d" % (max_depth, MAX_DEPTH))


def check(layout, resolution, camera_lanes, group, available, patches_only=False):
    """Refuse (``MemoryError`` / ``ValueError``) a layout whose iteration would need more
    than ``available`` bytes (None: not known, no memory check) or exceed 32-bit
    indices; warn above a quarter of the available memory."""
    sides = layout.sides * layout.count
    lanes = layout.lanes * layout.orders
    lines = int(resolution) ** 2 * layout.chains
    if lanes >= MAX_LANES or lines >= MAX_LANES or camera_lanes * group >= MAX_LANES:
        _refuse("chains=%d: %d lanes (chains x patch sides x orders), %d lines (resolution^2 x chains), %d camera "
                "samples per pass exceed 2^31 (32-bit indices); use fewer chains, a larger patch_size or a lower "
                "resolution" % (layout.chains, lanes, lines, camera_lanes * group))
    need = (layout.chains * chain_bytes(sides, resolution, layout.orders) + layout.count * BYTES_PER_PATCH
            + camera_lanes * group * BYTES_PER_CAMERA_SAMPLE)
    if available is None or need <= available / 4:
        return need
    fit = chains_that_fit(max(available - layout.count * BYTES_PER_PATCH, 0), sides, resolution, layout.orders)
    refuse = need > available
    text = ("ray_bundle: chains=%d x %d patch sides (%d patches) x %d order(s) = %.3g M lanes and %.3g M lines "
            "need about %.2f GB per iteration, %s the %.2f GB available"
            % (layout.chains, sides, layout.count, layout.orders, lanes / 1e6, lines / 1e6, need / 1e9,
               "more than" if refuse else "over a quarter of", available / 1e9))
    if refuse:
        raise MemoryError(text + "; valid range here: chains <= %d (or a larger patch_size, subdivide=false, a "
                          "lower resolution)" % fit)
    warnings.warn(text, RuntimeWarning, stacklevel=4)
    return need


def check_patches(patches, available):
    """Refuse a patch table that alone would not fit the available memory."""
    need = patches * BYTES_PER_PATCH
    if available is not None and need > available:
        raise MemoryError("ray_bundle: the scene divides into %d patch sides, whose table needs about %.2f GB, more "
                          "than the %.2f GB available; use a larger patch_size or subdivide=false"
                          % (patches, need / 1e9, available / 1e9))
