"""``qmc_lighttrace``'s particle phase for a whole render: a fixed number of paths in
``GROUPS`` consecutive ranges (their spread is the solution's per-patch error), or
Keller's adaptive termination (section 4), or deposits traced elsewhere (a distributed
render's sum). Results are kept on the integrator as numpy arrays (``irradiance``,
``paths_used``, ...; see its docstring), never the patch table: the table holds the
scene, which holds the integrator.
"""
import numpy as np

from mi_plugins.patches import refinement
from mi_plugins.patches.refinement import CHILDREN

from mi_plugins.solution.child_field import field_children
from mi_plugins.solution.patch_light import LUMINANCE, side_values
from mi_plugins.integrators.qmc_lighttrace.particles import trace_range
from mi_plugins.integrators.qmc_lighttrace.store import check_memory

#: consecutive ranges of the particle sequence traced one after the other; the spread of
#: their estimates gives the standard error per patch (paths: at least MIN_GROUP_PATHS each)
GROUPS = 8
MIN_GROUP_PATHS = 256
#: with ``refine``: the ranges after which patches may split (the later ones estimate the
#: refined patches)
REFINE_RANGES = 4


def particle_phase(integ, scene, table, seed, report=False, rendering=False, given=None, preview=None):
    """The particle phase of ``integ`` on ``scene`` (patches ``table``): returns (read tables
    (T, K, 2, 3), standard error of the last table (K, 2, 3) or None, the patch table:
    ``table`` refined where ``integ.refine`` split patches, its rounds in
    ``integ.refinements``). ``rendering``: skip the tracing where a render reads no stored
    light; ``given`` = (deposits, paths): traced elsewhere; ``preview(tables, paths, ranges
    done, ranges)`` after each range but the last."""
    layers = integ.layers
    check_memory(integ.plugin, layers, table.count * (CHILDREN if getattr(integ, "refine", False) else 1),
                 integ.max_depth)
    integ.delta_e_history, integ.refinements = [], []
    shape = (layers.count, table.count, 2, 3)
    error = None
    if given is not None:
        total, done = np.asarray(given[0], dtype=np.float64), int(given[1])
        if total.shape != shape:
            raise ValueError("qmc_lighttrace: the given particle deposits have shape %s; this scene and "
                             "max_depth need shape %s" % (total.shape, shape))
    elif rendering and layers.tables == 0:   # a render that reads no stored light
        total, done = np.zeros(shape), 0
    elif integ.epsilon is None and getattr(integ, "refine", False):
        total, done, table = _refining(integ, scene, table, seed, preview)
    elif integ.epsilon is None:
        total, done, error = _ranges(integ, scene, table, seed, preview)
    else:
        total, done = _adaptive(integ, scene, table, seed)
    areas = area_divisor(table)
    integ.paths_used = done
    integ.irradiance = total / max(done, 1) / areas[None, :, None, None]
    integ.reflected_radiance = integ.triangle_radiance = None
    if report:
        reflectance, emission = side_values(scene, table)
        integ.reflected_radiance = integ.irradiance.sum(axis=0) * reflectance
        integ.triangle_radiance = integ.reflected_radiance + emission
    integ.triangle_areas = table.areas_np
    integ.patch_shapes = np.array([shape.id() for shape in table.shapes])[table.shape_index_np]   # id per patch
    return layers.tables_from(integ.irradiance), error, table


def area_divisor(table):
    """The patch areas to divide deposits by: infinite for patches of no area (degenerate
    triangles of user meshes, never hit), whose irradiance is then 0, not NaN."""
    return np.where(table.areas_np > 0, table.areas_np, np.inf)


def _ranges(integ, scene, table, seed, preview):
    """``samples`` paths in GROUPS consecutive ranges: (deposits, paths, standard error of
    the last read table per patch side, or None with too few paths per range)."""
    n = int(integ.paths_for(table))
    groups = GROUPS if n >= GROUPS * MIN_GROUP_PATHS else 1
    bounds = [n * g // groups for g in range(groups + 1)]
    areas = area_divisor(table)[None, :, None, None]
    total, parts = np.zeros((integ.layers.count, table.count, 2, 3)), []
    for g in range(groups):      # a few ranges of the sequence, each one kernel per chunk
        deposit = trace_range(integ, scene, table, bounds[g], bounds[g + 1] - bounds[g], seed)[0]
        total += deposit
        if groups > 1:
            parts.append(integ.layers.tables_from(deposit / (bounds[g + 1] - bounds[g]) / areas)[-1:])
        if preview is not None and g + 1 < groups:
            preview(integ.layers.tables_from(total / bounds[g + 1] / areas), bounds[g + 1], g + 1, groups)
    if groups == 1 or not parts or not parts[0].size:
        return total, n, None
    stack = np.concatenate(parts)        # (groups, K, 2, 3): independent ranges, equal weights
    return total, n, stack.std(axis=0, ddof=1) / np.sqrt(groups)


def _refining(integ, scene, table, seed, preview):
    """``samples`` paths in GROUPS ranges, the patches refined after each of the first
    REFINE_RANGES (``mi_plugins.patches.refinement``): (deposits scaled to all the paths, paths,
    refined table). A patch's estimate comes from the paths traced since its parent was
    made (its share of the parent's children then, and its own deposits since): unbiased,
    every range being an unbiased estimate of every patch."""
    n = int(integ.paths_for(table))
    groups = GROUPS if n >= GROUPS * MIN_GROUP_PATHS else 1
    bounds = [n * g // groups for g in range(groups + 1)]
    layers, k = integ.layers.count, table.front_count
    total = np.zeros((layers, k, 2, 3))
    children, squares = np.zeros((layers, k, 2, CHILDREN, 3)), np.zeros((k, 2, CHILDREN))
    since, made = np.zeros(k), np.zeros(k)     # paths before each patch's estimate and children began
    budget = integ.max_patches or refinement.DEFAULT_BUDGET * k
    min_size = integ.min_patch_size if integ.min_patch_size is not None else table.h / 4.0
    for g in range(groups):
        deposit, _, found = trace_range(integ, scene, table, bounds[g], bounds[g + 1] - bounds[g], seed, children=True)
        total += deposit.sum(axis=3)
        children += deposit
        squares += found
        if g < min(REFINE_RANGES, groups - 1):
            split = refinement.choose(table, children.sum(axis=0) @ LUMINANCE, squares, integ.refine_threshold,
                                      min_size, budget, expected=None if integ.display == "gather" else field_children)
            if len(split):
                table, origin, which = refinement.refined(table, split)
                integ.refinements.append(split.tolist())
                child = which >= 0
                pick = np.maximum(which, 0)
                parent = np.take_along_axis(children[:, origin], pick[None, :, None, None, None], axis=3)[:, :, :, 0]
                total = np.where(child[None, :, None, None], parent, total[:, origin])
                since = np.where(child, made[origin], since[origin])
                made = np.where(child, bounds[g + 1], made[origin])
                children = np.where(child[None, :, None, None, None], 0.0, children[:, origin])
                squares = np.where(child[:, None, None], 0.0, squares[origin])
        if preview is not None and g + 1 < groups:
            done = bounds[g + 1] - since
            preview(integ.layers.tables_from(total / np.maximum(done, 1)[None, :, None, None]
                                             / area_divisor(table)[None, :, None, None]), bounds[g + 1], g + 1, groups)
    return total * (n / np.maximum(n - since, 1))[None, :, None, None], n, table


def _adaptive(integ, scene, table, seed):
    """Batches of ``batch`` paths until the patch irradiances change by less than
    ``epsilon`` ``patience`` times in a row (or ``max_samples``): (deposits, paths)."""
    areas, divisor = table.areas_np, np.pi * area_divisor(table)[:, None, None]
    total, emitted = np.zeros((integ.layers.count, table.count, 2, 3)), np.zeros(3)
    done, below, previous = 0, 0, None
    while done < integ.max_samples:
        n = min(integ.batch, integ.max_samples - done)
        deposit, power = trace_range(integ, scene, table, done, n, seed)
        total, emitted, done = total + deposit, emitted + power, done + n
        current = total.sum(axis=0) / done / divisor
        norm = max(float(np.abs(emitted).mean()) / done / np.pi, 1e-30)  # Phi / pi (= sum Le A of diffuse lights)
        if previous is not None:
            d = np.linalg.norm(current - previous, axis=2)
            delta_e = np.sqrt(np.sum(d * d * areas[:, None]) / np.sum(areas)) / norm
            integ.delta_e_history.append(delta_e)
            below = below + 1 if delta_e < float(integ.epsilon) else 0
            if below >= integ.patience:
                break
        previous = current
    return total, done
