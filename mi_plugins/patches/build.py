"""The patch table of a render: built once per scene and settings, split where patches
lie partly in the dark (:mod:`mi_plugins.patches.darkness`), and the patch parameters that
choose its resolution."""
from mi_plugins.base.fingerprint import scene_fingerprint
from mi_plugins.base.param_docs import Row
from mi_plugins.patches import tessellation
from mi_plugins.patches.darkness import split_in_the_dark
from mi_plugins.patches.meshtable import MeshTable

#: the patch table of the last render (one entry for every integrator of the process): a
#: display renders many views of one scene, and a table of a million triangles takes
#: seconds to build. Held here, not by an integrator, which its scene holds (a reference
#: cycle through C++ would keep every scene alive); this keeps the last scene alive only
_LAST = []


def cached_table(scene, who, h, back_sides=False, subdivide=True, cluster=True, before_build=None, dark_levels=0):
    """The :class:`MeshTable` of ``scene`` with these settings, its patches split
    ``dark_levels`` times where they lie partly in the dark or a surface cuts them
    (:mod:`mi_plugins.patches.darkness`),
    built again only when the scene object, its content (``mi_plugins.base.fingerprint``) or
    the settings differ from the last call's; ``before_build()`` (e.g. a memory check that
    predicts the patch count: seconds on a million triangles) is called only when a table
    is built."""
    key = (id(scene), scene_fingerprint(scene), float(h), bool(back_sides), bool(subdivide), bool(cluster),
           int(dark_levels))
    if not _LAST or _LAST[0][0] != key:
        if before_build is not None:
            before_build()
        table = MeshTable(scene, who, h=h, back_sides=back_sides, subdivide=subdivide, cluster=cluster)
        _LAST[:] = [(key, split_in_the_dark(table, dark_levels))]
    return _LAST[0][1]


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
