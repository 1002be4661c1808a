"""Flat per-triangle tables over all meshes of a Mitsuba scene.

Finite-element algorithms (``ray_bundle``, ``qmc_lighttrace``) keep one value
per triangle. :class:`MeshTable` numbers the triangles of all scene meshes
consecutively (mesh after mesh, in ``scene.shapes()`` order), maps a surface
interaction to its global triangle index, and builds surface interactions at
points of chosen triangles so that BSDFs, emitters and textures can be evaluated
there. Build it at the top level of an integrator's ``render()`` (not inside a
per-ray plugin method).
"""
import drjit as dr
import mitsuba as mi
import numpy as np


class NonMeshShapeError(ValueError):
    """A shape that is not a triangle mesh was given to a triangle-based algorithm."""


def require_meshes(scene, who):
    """Raise NonMeshShapeError naming the first non-mesh shape of ``scene``."""
    for shape in scene.shapes():
        if not isinstance(shape, mi.Mesh):
            raise NonMeshShapeError(
                "%s: shape '%s' (%s) is not a triangle mesh; this algorithm works on triangles. "
                "Use a mesh instead (a 'ply'/'obj' file, or mi_plugins.geometry.icosphere() / "
                "geometry='sphere_mesh' in mi_plugins.analytic)." % (who, shape.id(), _shape_kind(shape)))


def _shape_kind(shape):
    text = str(shape)
    return text.split("[", 1)[0].strip() or type(shape).__name__


class MeshTable:
    """All triangles of ``scene``'s meshes, numbered 0 .. count-1."""

    def __init__(self, scene, who="mi_plugins"):
        require_meshes(scene, who)
        self.scene = scene
        self.meshes = list(scene.shapes())
        face_counts = np.array([m.face_count() for m in self.meshes], dtype=np.int64)
        self.face_offsets = np.concatenate([[0], np.cumsum(face_counts)[:-1]]).astype(np.uint32)
        self.count = int(face_counts.sum())

        ids = np.array(dr.reinterpret_array(mi.UInt32, scene.shapes_dr()), dtype=np.int64)
        offset_by_id = np.zeros(int(ids.max()) + 1, dtype=np.uint32)
        offset_by_id[ids] = self.face_offsets
        index_by_id = np.zeros(int(ids.max()) + 1, dtype=np.uint32)
        index_by_id[ids] = np.arange(len(ids), dtype=np.uint32)
        self._offset_by_id = mi.UInt32(offset_by_id)
        self._index_by_id = mi.UInt32(index_by_id)

        p, uv, shape_index = [], [], []
        for k, mesh in enumerate(self.meshes):
            params = mi.traverse(mesh)
            verts = np.array(params["vertex_positions"], dtype=np.float64).reshape(-1, 3)
            faces = np.array(params["faces"], dtype=np.int64).reshape(-1, 3)
            p.append(verts[faces])
            if mesh.has_vertex_texcoords():
                uvs = np.array(params["vertex_texcoords"], dtype=np.float64).reshape(-1, 2)
                uv.append(uvs[faces])
            else:
                uv.append(np.tile(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), (len(faces), 1, 1)))
            shape_index.append(np.full(len(faces), k, dtype=np.uint32))
        p = np.concatenate(p)
        uv = np.concatenate(uv)
        cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        self.areas_np = 0.5 * np.linalg.norm(cross, axis=1)
        self.normals_np = cross / np.maximum(2 * self.areas_np[:, None], 1e-30)
        self.vertices_np = p
        self.shape_index_np = np.concatenate(shape_index)

        self.p0 = mi.Point3f(*p[:, 0].T)
        self.e1 = mi.Vector3f(*(p[:, 1] - p[:, 0]).T)
        self.e2 = mi.Vector3f(*(p[:, 2] - p[:, 0]).T)
        self.uv0 = mi.Point2f(*uv[:, 0].T)
        self.duv1 = mi.Vector2f(*(uv[:, 1] - uv[:, 0]).T)
        self.duv2 = mi.Vector2f(*(uv[:, 2] - uv[:, 0]).T)
        self.normal = mi.Normal3f(*self.normals_np.T)
        self.area = mi.Float(self.areas_np)
        self.shape_index = mi.UInt32(self.shape_index_np)

    @property
    def total_area(self):
        return float(self.areas_np.sum())

    def triangle_index(self, shape, prim_index):
        """Global triangle index of (shape pointer array, primitive index)."""
        shape_id = dr.reinterpret_array(mi.UInt32, shape)
        return dr.gather(mi.UInt32, self._offset_by_id, shape_id) + mi.UInt32(prim_index)

    def shape_pointer(self, tri):
        """ShapePtr of the mesh holding each triangle index."""
        idx = dr.gather(mi.UInt32, self.shape_index, tri)
        return dr.gather(mi.ShapePtr, self.scene.shapes_dr(), idx)

    def surface_interaction(self, tri, sample, wi_world=None):
        """SurfaceInteraction3f at a uniformly distributed point of each triangle
        ``tri`` (UInt32), with position, flat normal/frame, uv, shape and primitive."""
        b = mi.warp.square_to_uniform_triangle(sample)
        g = lambda arr, t: dr.gather(t, arr, tri)
        p0, e1, e2 = g(self.p0, mi.Point3f), g(self.e1, mi.Vector3f), g(self.e2, mi.Vector3f)
        uv0, duv1, duv2 = g(self.uv0, mi.Point2f), g(self.duv1, mi.Vector2f), g(self.duv2, mi.Vector2f)
        n = g(self.normal, mi.Normal3f)
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(tri))
        si.p = p0 + e1 * b.x + e2 * b.y
        si.uv = uv0 + duv1 * b.x + duv2 * b.y
        si.n = n
        si.sh_frame = mi.Frame3f(n)
        si.shape = self.shape_pointer(tri)
        si.prim_index = tri - dr.gather(mi.UInt32, mi.UInt32(self.face_offsets),
                                        dr.gather(mi.UInt32, self.shape_index, tri))
        si.time = 0.0
        si.t = 0.0
        si.wavelengths = dr.zeros(mi.Color0f) if hasattr(mi, "Color0f") else si.wavelengths
        if wi_world is not None:
            si.wi = si.to_local(wi_world)
        return si
