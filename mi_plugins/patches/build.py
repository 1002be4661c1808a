"""The patch table of a render: built once per scene and settings, split where patches
lie partly in the dark (:mod:`mi_plugins.patches.darkness`), and the patch parameters that
choose its resolution."""
import numpy as np

from mi_plugins.base import caches, fingerprint
from mi_plugins.base.param_docs import Row
from mi_plugins.patches import setup_cache, tessellation
from mi_plugins.patches.darkness import renumbered, split_in_the_dark
from mi_plugins.patches.meshtable import MeshTable

#: the patch table of the last render (one entry for every integrator of the process): a
#: display renders many views of one scene, and a table of a million triangles takes
#: seconds to build. Held here, not by an integrator, which its scene holds (a reference
#: cycle through C++ would keep every scene alive); this keeps the last scene alive only
_LAST = []
caches.register(_LAST.clear)


def cached_table(scene, who, h, back_sides=False, subdivide=True, cluster=True, before_build=None, dark_levels=0):
    """The :class:`MeshTable` of ``scene`` with these settings, its patches split
    ``dark_levels`` times where they lie partly in the dark or a surface cuts them
    (:mod:`mi_plugins.patches.darkness`),
    built again only when the scene object, its content (``mi_plugins.base.fingerprint``) or
    the settings differ from the last call's; ``before_build()`` (e.g. a memory check that
    predicts the patch count: seconds on a million triangles) is called only when a table
    is built."""
    with fingerprint.held(scene):        # (the key, the mesh parts and the dark rounds hash it once)
        key = (id(scene), fingerprint.scene_fingerprint(scene), float(h), bool(back_sides), bool(subdivide),
               bool(cluster), int(dark_levels))
        if not _LAST or _LAST[0][0] != key:
            if before_build is not None:
                before_build()
            table = MeshTable(scene, who, h=h, back_sides=back_sides, subdivide=subdivide, cluster=cluster)
            _LAST[:] = [(key, stored_splits(table, dark_levels))]
    return _LAST[0][1]


def stored_splits(table, dark_levels):
    """:func:`split_in_the_dark` of ``table``, its rounds kept in the setup cache
    (:mod:`mi_plugins.patches.setup_cache`) by the scene's content and the table's
    settings, with the shape order they were numbered in (a later load of the scene may
    order its shapes otherwise: the rounds are renumbered); the result's ``setup_key``
    names it there for the values derived from it."""
    settings = (setup_cache.scene_key(table.scene), table.h, bool(table.back_sides), table.settings,
                int(dark_levels))
    entry = setup_cache.key("dark rounds", settings)
    arrays, split = setup_cache.load(entry), None
    if arrays is not None:
        try:
            order = setup_cache.ShapeOrder(table, arrays[setup_cache.DIGESTS])
            rounds = setup_cache.unpack({k: v for k, v in arrays.items() if k != setup_cache.DIGESTS})["rounds"]
            split = renumbered(table, rounds, order.shape)[1]
        except (KeyError, IndexError, ValueError):        # (a damaged entry or another scene's)
            split = None
    if split is None:
        split = split_in_the_dark(table, dark_levels)
        arrays = dict(setup_cache.pack({"rounds": tuple(np.asarray(r, np.int64) for r in split.dark_rounds)}),
                      **{setup_cache.DIGESTS: setup_cache.digests_of(table)})
        setup_cache.store(entry, arrays)
    elif split is not table:
        split.dark_base = table
    split.setup_key = (settings, setup_cache.token(arrays))
    return split


#: the patch parameters of the finite-element integrators, read by :func:`patch_parameters`
PATCH_ROWS = (
    Row("patch_size", "float", "scene diagonal / 24",
        "> 0: the patch size h. Analytic shapes are divided into cells of about h x h, mesh triangles longer "
        "than sqrt(2) h into s x s similar sub-triangles (s <= 64). The stored light is constant per patch: a "
        "smaller h lowers the discretisation bias and raises the patch count"),
    Row("subdivide", "bool", "true", "split long mesh triangles (above); false keeps the triangles as modelled"),
    Row("cluster", "bool", "true",
        "group mesh triangles much smaller than the patch size (longest edge below h / 2) into patches of about "
        "h by grid cell and normal direction, so that the patch count follows the surface area, not the "
        "triangle count (``mi_plugins.patches.mesh_parts``); false: one patch per small triangle"),
)


def patch_parameters(p):
    """The patch parameters of a finite-element integrator, read with Params ``p``:
    ``patch_size`` (None: :func:`default_patch_size`), ``subdivide`` and ``cluster``."""
    size = p.float("patch_size", None, lo=0, lo_open=True, note="optional: default scene diagonal / %d"
                   % tessellation.CELLS_PER_DIAGONAL)
    return size, p.bool("subdivide", True), p.bool("cluster", True)
