"""The glTF 2.0 export of a solution's baked radiance (``mi_plugins.solution.gltf``), read back
with a maintained glTF reader (pygltflib): structure, vertex counts, index ranges, and
colours against the ``baked`` display at the same surface points. Test of the test: a
truncated file, swapped colour channels and an index past the vertices fail the check.
"""
import os
import struct

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import budget
import mi_plugins
from mi_plugins.solution import display
from mi_plugins.solution.export import baked_shapes
from test_solution import _floor_scene, _pixel_rays

pygltflib = pytest.importorskip("pygltflib", reason="the glTF reader of the tests (pip install 'mi-plugins[test]')")

TYPES = {5126: np.float32, 5125: np.uint32, 5123: np.uint16}
WIDTHS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}


def _panel():
    """A two-sided panel standing on the floor: both its sides receive light."""
    return {"panel": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0.6, 0.5, 0.2]).rotate(
        [0, 1, 0], 120).scale(0.4), "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse"}}}}


@pytest.fixture(scope="module")
def solved():
    scene = _floor_scene("mesh", _panel())
    integ = mi.load_dict({"type": "qmc_lighttrace", "samples": 20000})
    solution = mi_plugins.solve(scene, integ, seed=budget.seed(70))
    return scene, solution, integ.table_of(scene, solution)


def read(path):
    """(pygltflib document, accessor(index) -> (count, width) array), every accessor
    checked to lie inside its buffer view and the view inside the buffer."""
    doc = pygltflib.GLTF2().load(str(path))
    if str(path).endswith(".gltf"):
        doc.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
    blob = doc.binary_blob()
    assert len(doc.buffers) == 1 and doc.buffers[0].byteLength <= len(blob), "buffer shorter than declared"

    def accessor(index):
        a = doc.accessors[index]
        view = doc.bufferViews[a.bufferView]
        dtype, width = TYPES[a.componentType], WIDTHS[a.type]
        start = (view.byteOffset or 0) + (a.byteOffset or 0)
        assert start + a.count * width * np.dtype(dtype).itemsize <= (view.byteOffset or 0) + view.byteLength
        assert (view.byteOffset or 0) + view.byteLength <= doc.buffers[0].byteLength
        return np.frombuffer(blob, dtype, a.count * width, start).reshape(a.count, width)
    return doc, accessor


def check(path, scene, solution, table):
    """Assert that the glTF file at ``path`` holds ``solution``'s baked meshes (on its patch
    ``table``): structure, counts, index ranges, colour encoding, and side 0's radiance
    equal to the baked display's at the surface points one ray per pixel sees."""
    doc, accessor = read(path)
    extras = doc.extras["mi_plugins"]
    scale = extras["radiance_scale"]
    assert doc.asset.version == "2.0" and "KHR_materials_unlit" in doc.extensionsUsed
    assert doc.materials[0].extensions == {"KHR_materials_unlit": {}} and not doc.materials[0].doubleSided
    shapes = baked_shapes(solution)
    assert [n.name for n in doc.nodes] == [s[0] for s in shapes] and doc.scenes[0].nodes == list(range(len(shapes)))
    fronts, clipped = {}, 0
    for node, (name, positions, faces, front, back) in zip(doc.nodes, shapes):
        primitives = doc.meshes[node.mesh].primitives
        assert [p.extras["side"] for p in primitives] == ([0, 1] if np.any(back != 0) else [0]), name
        for p in primitives:
            xyz, index = accessor(p.attributes.POSITION), accessor(p.indices)[:, 0]
            color, radiance = accessor(p.attributes.COLOR_0), accessor(p.attributes._RADIANCE)
            normal = accessor(p.attributes.NORMAL)
            a = doc.accessors[p.attributes.POSITION]
            assert len(xyz) == len(positions) and np.allclose(xyz.min(axis=0), a.min) and np.allclose(xyz.max(axis=0), a.max)
            assert len(index) == 3 * len(faces) and index.min() >= 0 and index.max() < len(xyz), name
            assert len(color) == len(radiance) == len(normal) == len(xyz)
            assert np.allclose(np.linalg.norm(normal, axis=1), 1, atol=1e-5)
            assert color.min() >= 0 and color.max() <= 1
            assert np.allclose(color, np.clip(radiance / scale, 0, 1), atol=1e-6, rtol=1e-5)
            if p.extras["side"] == 1:
                assert np.allclose(radiance, back, rtol=1e-6, atol=1e-7), name
                fronts[name] += (radiance,)
                continue
            clipped += int(np.any(radiance > scale, axis=1).sum())
            fronts[name] = (xyz, index.reshape(-1, 3), radiance)
        for p in primitives[1:]:        # side 1: the same vertices, the triangles reversed
            assert np.array_equal(accessor(p.indices)[:, 0].reshape(-1, 3), fronts[name][1][:, ::-1])
    assert extras["clipped_vertices"] >= clipped
    # the radiance of the side seen interpolated over the file's triangles, at the points the pixels see
    meshes = {}
    for name, (xyz, tri, radiance, *back) in fronts.items():
        mesh = mi.Mesh(name, len(xyz), len(tri))
        params = mi.traverse(mesh)
        params["vertex_positions"] = mi.Float(xyz.astype(np.float32).ravel())
        params["faces"] = mi.UInt32(tri.astype(np.uint32).ravel())
        params.update()
        mesh.add_attribute("vertex_color", 3, mi.Float(radiance.astype(np.float32).ravel()))
        mesh.add_attribute("vertex_back", 3, mi.Float((back[0] if back else 0 * radiance).astype(np.float32).ravel()))
        meshes[name] = mesh
    exported = mi.load_dict(dict({"type": "scene"}, **meshes))
    ray = _pixel_rays(scene, 16)
    hit = exported.ray_intersect(ray)
    seen = np.array(hit.is_valid())
    behind = dr.dot(hit.n, ray.d) > 0          # (the winding is the patch normal: side 1 seen)
    got = np.array(dr.select(behind, hit.shape.eval_attribute_3("vertex_back", hit, hit.is_valid()),
                             hit.shape.eval_attribute_3("vertex_color", hit, hit.is_valid())))
    si = scene.ray_intersect(ray)
    view = display.View(solution, table, "baked")
    baked = np.array(view.baked(si, mi.UInt32(0), si.is_valid()))      # (the scene has no emitting shape)
    assert np.array_equal(seen, np.array(si.is_valid())) and seen.sum() > 100 and np.array(behind).sum() > 10
    floor = seen & (np.array(si.n.y) > 0.5) & (np.array(si.p.y) < 1e-3)     # the mesh: linear in the display too
    assert floor.sum() > 50
    assert np.abs(got - baked)[:, floor].max() < 1e-4 * baked.max()
    assert np.abs(got - baked)[:, seen].max() < 0.05 * baked.max()
    del exported, meshes, hit


@pytest.mark.parametrize("extension", [".glb", ".gltf"])
def test_the_gltf_file_holds_the_baked_meshes(solved, tmp_path, extension):
    scene, solution, table = solved
    path = solution.to_gltf(str(tmp_path / ("room" + extension)))
    check(path, scene, solution, table)
    print("%s: %d bytes" % (extension, os.path.getsize(path)))


def _rewrite_glb(path, out, edit):
    """A copy of the .glb at ``path`` whose (document, binary) went through ``edit``."""
    import json
    data = open(path, "rb").read()
    n = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + n])
    blob = bytearray(data[20 + n + 8:])
    doc, blob = edit(doc, blob)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    with open(out, "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + len(blob)))
        f.write(struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(blob), b"BIN\0") + blob)
    return out


def _view_of(doc, attribute, shape="floor"):
    """(byte offset, count) of ``attribute`` ('indices' or a vertex attribute) of the
    side-0 primitive of ``shape``'s mesh."""
    node = next(n for n in doc["nodes"] if n["name"] == shape)
    p = doc["meshes"][node["mesh"]]["primitives"][0]
    a = doc["accessors"][p["indices"] if attribute == "indices" else p["attributes"][attribute]]
    v = doc["bufferViews"][a["bufferView"]]
    return v["byteOffset"] + a.get("byteOffset", 0), a["count"]


def test_a_corrupted_file_or_wrong_colours_fail_the_check(solved, tmp_path):
    """Test of the test: a BIN chunk cut short, a floor whose colours have their red and
    blue swapped, and a triangle pointing past the vertices."""
    scene, solution, table = solved
    path = solution.to_gltf(str(tmp_path / "room.glb"))

    def truncated(doc, blob):
        return doc, blob[:len(blob) - 64]

    def swapped(doc, blob):
        for attribute in ("COLOR_0", "_RADIANCE"):
            start, count = _view_of(doc, attribute)
            rgb = np.frombuffer(bytes(blob[start:start + 12 * count]), np.float32).reshape(-1, 3)
            blob[start:start + 12 * count] = rgb[:, ::-1].copy().tobytes()
        return doc, blob

    def past_the_end(doc, blob):
        start, _ = _view_of(doc, "indices")
        vertices = _view_of(doc, "POSITION")[1]
        blob[start:start + 4] = struct.pack("<I", vertices)
        return doc, blob

    for edit in (truncated, swapped, past_the_end):
        bad = _rewrite_glb(path, str(tmp_path / (edit.__name__ + ".glb")), edit)
        with pytest.raises(AssertionError):
            check(bad, scene, solution, table)
    check(_rewrite_glb(path, str(tmp_path / "same.glb"), lambda d, b: (d, b)), scene, solution, table)


def test_an_incomplete_solution_or_a_bad_name_is_refused(solved, tmp_path):
    scene, solution, table = solved
    with pytest.raises(ValueError, match=r"must end in \.glb .* or \.gltf"):
        solution.to_gltf(str(tmp_path / "room.obj"))
    bare = mi_plugins.solution.solution.Solution(solution.tables, solution.areas, solution.meta)
    with pytest.raises(ValueError, match="Solution.to_gltf: this solution is not complete"):
        bare.to_gltf(str(tmp_path / "room.glb"))
    broken = mi_plugins.solution.solution.Solution(solution.tables, solution.areas, solution.meta, field=solution.field,
                                          radiance=solution.radiance.copy(), emission=solution.emission)
    broken.radiance[3, 0, 1] = np.nan
    with pytest.raises(ValueError, match=r"Solution.to_gltf: the solution's radiance is not finite at [1-9]\d* of"):
        broken.to_gltf(str(tmp_path / "room.glb"))
    assert not os.listdir(tmp_path)
