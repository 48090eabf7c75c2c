"""The triangle table of a big scene is deferred (kernels.geometry.TriangleTable, deferred=True): the BVH
is built first and the table on a thread while the first samples render, which compute the rows they
gather from the scene's arrays meanwhile. Both ways must give the same rows bit for bit, and so the same
image."""
from __future__ import annotations

import numpy as np
import pytest

from ember.kernels import Renderer, RenderSettings
from ember.kernels import geometry
from ember.kernels.geometry import TriangleTable, flatten_instances

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
    assert deferred._rows is None        # nothing built yet: gathers compute their rows
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
    assert deferred._rows is None
    deferred.build_rows()
    deferred.build_rows()                # a second call starts nothing more
    deferred._building.join()
    assert deferred._rows is not None and deferred._source is None
    check()
    np.testing.assert_array_equal(deferred.rows, eager.rows)
    # .rows builds the table when it is asked for before build_rows.
    late = TriangleTable(scene, deferred=True)
    np.testing.assert_array_equal(late.rows, eager.rows)


def test_small_or_instanced_scenes_build_at_once(monkeypatch):
    scene = _plain_scene()
    assert len(scene.positions) < geometry.DEFERRED_ROWS
    assert TriangleTable(scene, deferred=True)._rows is not None
    # Instances place their rows as they are gathered: their table is never deferred, whatever its size.
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    assert TriangleTable(_scene().validate().scene, deferred=True)._rows is not None
    assert TriangleTable(scene, deferred=True)._rows is None


@pytest.mark.parametrize("mode", ["computed", "built"])
def test_renders_are_the_same_deferred_or_not(monkeypatch, mode):
    """Whether every gather computes its rows (the table never built) or the table is there for the first
    wave, the image is the same bit for bit as with the table built at once."""
    scene = _plain_scene()
    settings = RenderSettings(samples=4, seed=5)
    with Renderer(scene, threads=2) as renderer:
        assert renderer._triangles._rows is not None
        reference = renderer.render(settings).image
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    if mode == "computed":
        monkeypatch.setattr(TriangleTable, "build_rows", lambda self: None)
    with Renderer(scene, threads=2) as renderer:
        if mode == "built":
            renderer._triangles.build_rows()
            renderer._triangles._building.join()
        image = renderer.render(settings).image
        assert (renderer._triangles._rows is None) == (mode == "computed")
    np.testing.assert_array_equal(image, reference)


def test_the_table_is_built_once_a_render_has_more_than_its_quick_first_pass(monkeypatch):
    """A 1-sample render (the first image of an F12) computes the rows it gathers and never builds the
    table; a render with more passes starts building it with its second pass."""
    monkeypatch.setattr(geometry, "DEFERRED_ROWS", 1)
    with Renderer(_plain_scene(), threads=2) as renderer:
        renderer.render(RenderSettings(samples=1, seed=5))
        assert renderer._triangles._building is None and renderer._triangles._rows is None
        renderer.render(RenderSettings(samples=4, seed=5))
        assert renderer._triangles._building is not None
        renderer._triangles._building.join()
        assert renderer._triangles._rows is not None
