"""Coverage rows of meshes as users' files bring them.

The other rows' meshes are flat shaded (``face_normals``) and consistently wound. A ``ply``
or ``obj`` file without normals gets vertex normals that Mitsuba averages from the faces
around each shared vertex (smooth shading), and scanned or converted meshes are often
wound inconsistently: there the averaged normals point to the other side of their
triangles over whole regions, which the finite-element integrators refuse
(:mod:`mi_plugins.patches.normals`).
"""
import numpy as np

from mi_plugins.verify import geometry
from mi_plugins.verify.conformance.meshes import diffuse
from mi_plugins.verify.coverage.stage import ALBEDO, stage, subject_transform

#: share of the subject's triangles listed clockwise in the inconsistent-winding row
FLIPPED_SHARE = 0.3


def smooth_sphere(rings=8, segments=16, flipped_share=0.0, seed=7):
    """A unit sphere of shared vertices (so that Mitsuba averages smooth vertex normals),
    wound outward; ``flipped_share`` of its triangles (drawn with ``seed``) wound inward."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    verts = np.concatenate([[[0.0, 1.0, 0.0]], ring, [[0.0, -1.0, 0.0]]])
    top, bottom = 0, len(verts) - 1
    at = lambda i, j: 1 + i * segments + j % segments      # noqa: E731
    faces = [(top, at(0, j + 1), at(0, j)) for j in range(segments)]
    for i in range(rings - 2):
        for j in range(segments):
            faces += [(at(i, j), at(i, j + 1), at(i + 1, j)), (at(i, j + 1), at(i + 1, j + 1), at(i + 1, j))]
    faces += [(bottom, at(rings - 2, j), at(rings - 2, j + 1)) for j in range(segments)]
    faces = np.array(faces, dtype=np.int64)
    centre = verts[faces].mean(axis=1)
    normal = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    inward = np.einsum("ij,ij->i", normal, centre) < 0
    faces[inward] = faces[inward][:, ::-1]                 # every triangle outward first
    flip = np.random.default_rng(seed).random(len(faces)) < flipped_share
    faces[flip] = faces[flip][:, ::-1]
    uvs = np.stack([np.arctan2(verts[:, 2], verts[:, 0]) / (2 * np.pi) + 0.5, verts[:, 1] * 0.5 + 0.5], axis=1)
    return geometry.TriangleMesh(verts, faces, uvs)


def _subject(mesh, name, bsdf):
    """The stage's subject as a ``ply`` file without normals (Mitsuba averages them)."""
    return {"type": "ply", "filename": geometry.mesh_file(mesh, name), "to_world": subject_transform(), "bsdf": bsdf}


def mesh_rows(Row):
    """The rows (``Row``: the coverage row class)."""
    twosided = {"type": "twosided", "bsdf": diffuse(ALBEDO)}
    return [
        Row("case:vertex_normals", None, lambda r: stage(r, subject=_subject(
            smooth_sphere(), "coverage_smooth_sphere", diffuse(ALBEDO))),
            note="a sphere mesh of shared vertices without normals in its file: Mitsuba's averaged vertex normals "
                 "(smooth shading)"),
        Row("case:inconsistent_winding", None, lambda r: stage(r, subject=_subject(
            smooth_sphere(flipped_share=FLIPPED_SHARE), "coverage_mixed_winding", twosided)),
            note="the same sphere, 30 % of its triangles wound inward, twosided diffuse: the averaged normals point "
                 "to the other side of their triangles on a fifth of its area (21.9 %)")]
