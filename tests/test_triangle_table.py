"""The triangle table of a big scene is deferred (kernels.geometry.TriangleTable, deferred=True): the BVH
is built first and the table on a thread from the render's second pass on; the samples before compute
the rows they gather from the scene's arrays. Both ways must give the same rows bit for bit, and so the
same image; so must normals kept as rows and gathered by index (kernels.scene.CornerRows)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ember.kernels import Renderer, RenderSettings
from ember.kernels.geometry import triangles as geometry
from ember.kernels.geometry import TriangleTable, extent, flatten_instances
from ember.kernels.scene import CornerRows

from test_instancing import _scene


def _plain_scene():
    """test_instancing's scene flattened (no instances), with tangents, a zero corner normal and
    random UVs."""
    scene = flatten_instances(_scene().validate().scene)
    scene.normals[3, 1] = 0.0          # falls back to the face normal, in both ways
    scene.uvs[:] = np.random.default_rng(2).uniform(size=scene.uvs.shape).astype(np.float32)
    return scene.validate().scene


def test_deferred_rows_equal_the_built_table(monkeypatch):
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    scene = _plain_scene()
    eager, deferred = TriangleTable(scene), TriangleTable(scene, deferred=True)
    assert not deferred.rows_built        # nothing built yet: gathers compute their rows
    total = len(scene.positions)
    prim = np.random.default_rng(1).integers(0, total, 3 * total).astype(np.int32)
    b1 = np.random.default_rng(3).uniform(0, 0.5, len(prim)).astype(np.float32)
    b2 = np.random.default_rng(4).uniform(0, 0.5, len(prim)).astype(np.float32)

    def check():
        np.testing.assert_array_equal(deferred.gather(prim), eager.gather(prim))
        np.testing.assert_array_equal(deferred.materials(prim), eager.materials(prim))
        for got, want in zip(deferred.tangent_frame(prim, b1, b2), eager.tangent_frame(prim, b1, b2)):
            np.testing.assert_array_equal(np.asarray(got), np.asarray(want))

    check()
    assert not deferred.rows_built
    deferred.build_rows()
    deferred.build_rows()                # a second call starts nothing more
    deferred.wait_rows()
    assert deferred.rows_built and deferred._source is None
    check()
    np.testing.assert_array_equal(deferred.rows, eager.rows)
    # .rows builds the table when it is asked for before build_rows.
    late = TriangleTable(scene, deferred=True)
    np.testing.assert_array_equal(late.rows, eager.rows)


def test_a_mesh_without_uvs_gives_the_same_rows_as_zeros(monkeypatch):
    """A mesh without UVs exports one zero row seen by every corner (a zero-stride view): validation, the
    deferred gathers and the built table read it as the array of zeros it stands for, without copying it."""
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    dense = _plain_scene()
    dense.uvs[:] = 0.0
    view = dataclasses.replace(dense, uvs=np.broadcast_to(np.zeros((1, 1, 2), np.float32), dense.uvs.shape))
    view = view.validate().scene
    assert view.uvs.strides[0] == 0      # validation keeps the view
    eager, deferred = TriangleTable(dense), TriangleTable(view, deferred=True)
    prim = np.random.default_rng(1).integers(0, len(dense.positions), 200).astype(np.int32)
    np.testing.assert_array_equal(deferred.gather(prim), eager.gather(prim))
    deferred.build_rows()
    deferred.wait_rows()
    np.testing.assert_array_equal(deferred.rows, eager.rows)
    # A non-finite row seen by every corner is repaired to zeros, as the array would be.
    bad = dataclasses.replace(dense, uvs=np.broadcast_to(np.full((1, 1, 2), np.nan, np.float32), dense.uvs.shape))
    np.testing.assert_array_equal(bad.validate().scene.uvs, 0.0)


def test_small_or_instanced_scenes_build_at_once(monkeypatch):
    scene = _plain_scene()
    assert len(scene.positions) < geometry.DEFERRED_ROWS
    assert TriangleTable(scene, deferred=True).rows_built
    # Instances place their rows as they are gathered: their table is never deferred, whatever its size.
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    assert TriangleTable(_scene().validate().scene, deferred=True).rows_built
    assert not TriangleTable(scene, deferred=True).rows_built


@pytest.mark.parametrize("mode", ["computed", "built"])
def test_renders_are_the_same_deferred_or_not(monkeypatch, mode):
    """Whether every gather computes its rows (the table never built) or the table is there for the first
    wave, the image is the same bit for bit as with the table built at once."""
    scene = _plain_scene()
    settings = RenderSettings(samples=4, seed=5)
    with Renderer(scene, threads=2) as renderer:
        assert renderer.triangles.rows_built
        reference = renderer.render(settings).image
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    if mode == "computed":
        monkeypatch.setattr(TriangleTable, "build_rows", lambda self: None)
    with Renderer(scene, threads=2) as renderer:
        if mode == "built":
            renderer.triangles.build_rows()
            renderer.triangles.wait_rows()
        image = renderer.render(settings).image
        assert (not renderer.triangles.rows_built) == (mode == "computed")
    np.testing.assert_array_equal(image, reference)


def test_the_table_is_built_once_a_render_has_more_than_its_quick_first_pass(monkeypatch):
    """A 1-sample render (the first image of an F12) computes the rows it gathers and never builds the
    table; a render with more passes starts building it with its second pass."""
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    with Renderer(_plain_scene(), threads=2) as renderer:
        renderer.render(RenderSettings(samples=1, seed=5))
        assert not renderer.triangles.building and not renderer.triangles.rows_built
        renderer.render(RenderSettings(samples=4, seed=5))
        assert renderer.triangles.building
        renderer.triangles.wait_rows()
        assert renderer.triangles.rows_built


def _assert_same_image(a, b, seed: int) -> None:
    """Scenes a and b render the same image bit for bit (4 samples, 2 threads)."""
    images = []
    for scene in (a, b):
        with Renderer(scene, threads=2) as renderer:
            images.append(renderer.render(RenderSettings(samples=4, seed=seed)).image)
    np.testing.assert_array_equal(images[0], images[1])


def _indexed_normals(scene):
    """The scene's normals as CornerRows: each distinct corner normal once, and every corner's row."""
    rows, index = np.unique(scene.normals.reshape(-1, 3), axis=0, return_inverse=True)
    return CornerRows(rows.astype(np.float32), index.reshape(-1, 3).astype(np.uint32))


def test_normals_kept_by_rows_give_the_same_table_and_image(monkeypatch):
    """SceneArrays.normals as CornerRows (what the export hands over) stands for its (T, 3, 3) array: the
    same table rows bit for bit, eager, deferred and computed, the same validation and the same image."""
    scene = _plain_scene()
    indexed = dataclasses.replace(scene, normals=_indexed_normals(scene))
    assert isinstance(indexed.normals, CornerRows) and indexed.normals.shape == scene.normals.shape
    np.testing.assert_array_equal(np.asarray(indexed.normals), scene.normals)
    checked = indexed.validate()
    assert checked.scene.normals is indexed.normals and checked.repaired_normals == 0
    np.testing.assert_array_equal(TriangleTable(indexed).rows, TriangleTable(scene).rows)
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    monkeypatch.setattr(geometry, "_PARALLEL_ROWS", 7)     # slices of the rows gathered per thread
    deferred = TriangleTable(indexed, deferred=True)
    prim = np.random.default_rng(5).integers(0, len(scene.positions), 500).astype(np.int32)
    np.testing.assert_array_equal(deferred.gather(prim), TriangleTable(scene).gather(prim))
    np.testing.assert_array_equal(deferred.rows, TriangleTable(scene).rows)
    _assert_same_image(scene, indexed, seed=2)


def test_corner_rows_are_validated_and_repaired_like_the_array():
    scene = _plain_scene()
    normals = _indexed_normals(scene)
    bad_index = CornerRows(normals.rows, np.full_like(normals.index, len(normals.rows)))
    with pytest.raises(ValueError, match="normals.index"):
        dataclasses.replace(scene, normals=bad_index).validate()
    with pytest.raises(ValueError, match="normals.rows"):
        dataclasses.replace(scene, normals=CornerRows(normals.rows.astype(np.float64), normals.index)).validate()
    # A non-finite row spoils every corner that reads it: those triangles get the face normal, as with
    # the array (the repaired normals are then an array).
    rows = normals.rows.copy()
    rows[normals.index[4, 2]] = np.nan
    dense = np.asarray(CornerRows(rows, normals.index))
    a = dataclasses.replace(scene, normals=CornerRows(rows, normals.index)).validate()
    b = dataclasses.replace(scene, normals=dense).validate()
    assert a.repaired_normals == b.repaired_normals > 0
    np.testing.assert_array_equal(a.scene.normals, b.scene.normals)


def _indexed_positions(scene):
    vertices, index = np.unique(scene.positions.reshape(-1, 3), axis=0, return_inverse=True)
    return vertices.astype(np.float32), index.reshape(-1, 3).astype(np.uint32)


def test_corners_kept_as_indexed_vertices_give_the_same_scene(monkeypatch):
    """SceneArrays.positions as CornerRows over the BVH's vertices and indices (what the export hands over):
    the same bounds, table rows, triangles by slice, numbers and mask, and image bit for bit as the corner array; a
    triangle that validation drops leaves an array of the others."""
    scene = _plain_scene()
    vertices, index = _indexed_positions(scene)
    indexed = dataclasses.replace(scene, positions=CornerRows(vertices, index), normals=_indexed_normals(scene),
                                  bvh_vertices=vertices, bvh_indices=index)
    checked = indexed.validate()
    assert checked.dropped_triangles == 0 and checked.scene.positions is indexed.positions
    for a, b in zip(extent(indexed.positions), extent(scene.positions)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(TriangleTable(indexed).rows, TriangleTable(scene).rows)
    prim = np.arange(0, len(scene.positions), 3)
    np.testing.assert_array_equal(indexed.positions[prim], scene.positions[prim])
    np.testing.assert_array_equal(indexed.positions[3:9], scene.positions[3:9])
    mask = np.arange(len(scene.positions)) % 2 == 0
    np.testing.assert_array_equal(indexed.positions[mask], scene.positions[mask])
    _assert_same_image(scene, indexed, seed=7)
    # A collapsed triangle is dropped: the others stay, now as an array, with their BVH indices.
    collapsed = index.copy()
    collapsed[2, 1] = collapsed[2, 0]
    bad = dataclasses.replace(indexed, positions=CornerRows(vertices, collapsed), bvh_indices=collapsed)
    result = bad.validate()
    assert result.dropped_triangles == 1 and isinstance(result.scene.positions, np.ndarray)
    np.testing.assert_array_equal(result.scene.positions, np.delete(vertices[collapsed], 2, axis=0))
    np.testing.assert_array_equal(result.scene.bvh_vertices[result.scene.bvh_indices], result.scene.positions)
