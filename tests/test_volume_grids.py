"""Voxel grids (kernels/media/grid.py) and their export from Blender (engine/export/volumes.py): .vdb files
written here with Blender's own openvdb module, loaded as Volume objects in headless bpy, read back and
looked up against the fields written (closed forms at voxel points, cell middles and inside the grid), the
transform, the bounds, the warnings; geometry-nodes volumes and smoke domains."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from bpy_helpers import camera_only_scene, export_current  # noqa: E402
from ember.engine.export.volumes import (boundary_mesh, fluid_grid, is_volume,  # noqa: E402
                                         openvdb_module, read_volume)
from ember.kernels.media.grid import PADDING, VoxelGrid  # noqa: E402

vdb = openvdb_module()
pytestmark = pytest.mark.skipif(vdb is None, reason="Blender's openvdb module is not found")

# A rotation about z by 30 degrees, voxels of 0.2 x 0.3 x 0.5, then a translation: the index -> object map of
# the 'ramp' grid, column-vector convention (OpenVDB's 4 x 4 is its transpose: row vectors).
_C, _S = np.cos(np.pi / 6), np.sin(np.pi / 6)
RAMP_INDEX_TO_OBJECT = np.array([[_C * 0.2, -_S * 0.3, 0, 1.5], [_S * 0.2, _C * 0.3, 0, -0.5],
                                 [0, 0, 0.5, 0.25], [0, 0, 0, 1]])
RAMP_LO = np.array([-3, 2, 5])           # the index of the first voxel written
RAMP_SHAPE = (12, 9, 7)
SPHERE_RADIUS = 6.0                       # voxels; the sphere's grid has unit voxels and no transform


def ramp(ijk):
    """An affine field of index coordinates, positive over the ramp grid: Linear and Cubic interpolation
    reproduce it exactly wherever their taps are all inside the grid."""
    ijk = np.asarray(ijk, dtype=np.float64)
    return 2.0 + 0.5 * ijk[..., 0] - 0.25 * ijk[..., 1] + 0.125 * ijk[..., 2]


def colour(ijk):
    ijk = np.asarray(ijk, dtype=np.float64)
    return np.stack([0.1 * ijk[..., 0], 1.0 - 0.05 * ijk[..., 1], 0.5 + 0.02 * ijk[..., 2]], axis=-1)


def sphere(ijk):
    """Density 1 - r^2 / R^2 inside the sphere of radius R about the origin, 0 outside."""
    r2 = (np.asarray(ijk, dtype=np.float64) ** 2).sum(axis=-1)
    return np.maximum(0.0, 1.0 - r2 / SPHERE_RADIUS ** 2)


def index_grid(shape, lo=(0, 0, 0)):
    return np.stack(np.meshgrid(*(np.arange(n) + o for n, o in zip(shape, lo)), indexing="ij"), axis=-1)


def to_object(ijk, index_to_object=RAMP_INDEX_TO_OBJECT):
    ijk = np.asarray(ijk, dtype=np.float64)
    return (ijk @ index_to_object[:3, :3].T + index_to_object[:3, 3]).astype(np.float32)


def write_vdb(path):
    """density: the sphere; ramp: the affine field with RAMP_INDEX_TO_OBJECT; color: a Vec3 field on the
    ramp's voxels."""
    density = vdb.FloatGrid()
    density.name = "density"
    n = int(SPHERE_RADIUS) + 1
    density.copyFromArray(sphere(index_grid((2 * n + 1,) * 3, (-n,) * 3)).astype(np.float32), ijk=(-n, -n, -n))
    ramp_grid = vdb.FloatGrid()
    ramp_grid.name = "ramp"
    ramp_grid.copyFromArray(ramp(index_grid(RAMP_SHAPE, RAMP_LO)).astype(np.float32), ijk=tuple(map(int, RAMP_LO)))
    ramp_grid.transform = vdb.createLinearTransform(RAMP_INDEX_TO_OBJECT.T.tolist())
    colour_grid = vdb.Vec3SGrid()
    colour_grid.name = "color"
    colour_grid.copyFromArray(colour(index_grid(RAMP_SHAPE, RAMP_LO)).astype(np.float32),
                              ijk=tuple(map(int, RAMP_LO)))
    colour_grid.transform = vdb.createLinearTransform(RAMP_INDEX_TO_OBJECT.T.tolist())
    vdb.write(str(path), grids=[density, ramp_grid, colour_grid])


@pytest.fixture
def scene():
    """An empty factory scene; every object and datablock a test adds is removed after it."""
    scene = camera_only_scene()
    before = {kind: set(getattr(bpy.data, kind)) for kind in ("objects", "meshes", "volumes", "node_groups")}
    yield scene
    for kind, old in before.items():
        collection = getattr(bpy.data, kind)
        for block in [block for block in collection if block not in old]:
            collection.remove(block)


def volume_object(scene, filepath, name="Vol"):
    volume = bpy.data.volumes.new(name)
    volume.filepath = str(filepath)
    ob = bpy.data.objects.new(name, volume)
    scene.collection.objects.link(ob)
    return ob


def read(ob, interpolation="LINEAR"):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    return read_volume(ob.evaluated_get(depsgraph), depsgraph.scene.frame_current, interpolation)


@pytest.fixture(scope="module")
def vdb_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("vdb") / "fields.vdb"
    write_vdb(path)
    return path


@pytest.fixture
def fields(scene, vdb_file):
    source = read(volume_object(scene, vdb_file))
    assert source.warnings == []
    return source


# ---- Lookups against the fields written ----------------------------------------------------------------

def test_grids_read_by_name_with_their_channels(fields):
    assert set(fields.grids) == {"density", "ramp", "color"}
    assert fields.kind == "VOLUME"
    assert fields.grids["density"].channels == 1 and fields.grids["color"].channels == 3
    assert fields.grids["ramp"].shape == RAMP_SHAPE


def test_linear_at_voxel_points_and_cell_middles(fields):
    density = fields.grids["density"]
    ijk = index_grid((9, 9, 9), (-4, -4, -4)).reshape(-1, 3)
    np.testing.assert_allclose(density.lookup(ijk.astype(np.float32), "LINEAR")[:, 0], sphere(ijk), atol=1e-6)
    # A cell's middle is the mean of its eight corners.
    corners = ijk[:, None, :] + index_grid((2, 2, 2)).reshape(1, 8, 3)
    middle = density.lookup((ijk + 0.5).astype(np.float32), "LINEAR")[:, 0]
    np.testing.assert_allclose(middle, sphere(corners).mean(axis=1), atol=1e-6)


def test_linear_and_cubic_reproduce_the_affine_field_through_the_transform(fields):
    rng = np.random.default_rng(7)
    # Inside by two voxels, so that Cubic's taps (floor - 1 ... floor + 2) all hold written values.
    ijk = RAMP_LO + 1 + rng.random((500, 3)) * (np.array(RAMP_SHAPE) - 4)
    points = to_object(ijk)
    for interpolation in ("LINEAR", "CUBIC"):
        np.testing.assert_allclose(fields.grids["ramp"].lookup(points, interpolation)[:, 0], ramp(ijk), atol=2e-5)
        np.testing.assert_allclose(fields.grids["color"].lookup(points, interpolation), colour(ijk), atol=2e-5)


def test_closest_reads_the_voxel_at_floor_of_the_index_point(fields):
    """Cycles reads voxel floor(P): voxel i answers for [i, i + 1), not for the points nearest to it."""
    grid = fields.grids["ramp"]
    ijk = RAMP_LO + index_grid((5, 4, 3)).reshape(-1, 3) + 1
    for offset, voxel in ((0.5, ijk), (0.9, ijk), (-0.1, ijk - 1)):
        np.testing.assert_allclose(grid.lookup(to_object(ijk + offset), "CLOSEST")[:, 0], ramp(voxel), atol=1e-6)


def test_transform_maps_an_object_point_to_its_voxel_as_blender_does(scene, fields, vdb_file):
    """The grid's index -> object map is the one Blender reports for the grid (VolumeGrid.matrix_object),
    offset to the first voxel stored."""
    ob = volume_object(scene, vdb_file, "Check")
    grid = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data.grids["ramp"]
    blender = np.array(grid.matrix_object)
    np.testing.assert_allclose(blender, RAMP_INDEX_TO_OBJECT, atol=1e-6)
    voxel = np.array([4, 3, 2])              # of the stored block: index RAMP_LO + voxel
    point = fields.grids["ramp"].index_to_object @ np.append(voxel, 1.0)
    np.testing.assert_allclose(point, blender @ np.append(RAMP_LO + voxel, 1.0), atol=1e-9)
    np.testing.assert_allclose(fields.grids["ramp"].index_coordinates(point[None, :3]), [voxel], atol=1e-9)


def test_background_outside_the_stored_block(fields):
    density = fields.grids["density"]
    far = np.array([[40.0, 0, 0], [0, -40.0, 3], [0, 0, 100.0]], dtype=np.float32)
    for interpolation in ("CLOSEST", "LINEAR", "CUBIC"):
        assert np.all(density.lookup(far, interpolation) == 0)


def test_bounds_enclose_the_active_voxels_and_the_padding(fields):
    ramp_grid = fields.grids["ramp"]
    corners = index_grid((2, 2, 2)).reshape(-1, 3) * (np.array(RAMP_SHAPE) - 1) + RAMP_LO
    for padding in (0, 1, 2):
        grown = corners + padding * np.where(corners > RAMP_LO, 1, -1)
        expected = to_object(grown)
        np.testing.assert_allclose(ramp_grid.bounds(padding), [expected.min(axis=0), expected.max(axis=0)],
                                   atol=1e-5)
    # The sphere's active voxels are those above Volume > Render > Clipping (0.001 by default).
    inside = index_grid((15, 15, 15), (-7, -7, -7)).reshape(-1, 3)
    extent = np.abs(inside[sphere(inside) > 0.001]).max()
    np.testing.assert_allclose(fields.grids["density"].bounds(), [[-extent] * 3, [extent] * 3])


def test_boundary_is_a_closed_outward_box_around_the_padded_voxels(fields):
    assert fields.triangles.shape == (12, 3) and fields.vertices.dtype == np.float32
    for padding in (0, 1, 2):
        vertices, triangles = boundary_mesh([fields.grids["density"]], padding)
        a, b, c = (vertices[triangles[:, n]].astype(np.float64) for n in range(3))
        signed_volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6
        side = 2 * (SPHERE_RADIUS - 1 + padding)       # the clipping leaves the voxels |i| <= 5
        assert signed_volume == pytest.approx(side ** 3)
        edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
        assert np.all(np.unique(edges, axis=0, return_counts=True)[1] == 2)


# ---- Blender's side: files, sequences, geometry nodes, smoke --------------------------------------------

def test_openvdb_module_is_blenders_own():
    assert vdb.LIBRARY_VERSION[0] >= 11 and hasattr(vdb, "readAll")


def test_missing_file_warns_with_its_path(scene, tmp_path):
    missing = tmp_path / "nowhere.vdb"
    source = read(volume_object(scene, missing))
    assert source.grids == {} and len(source.triangles) == 0
    assert len(source.warnings) == 1 and str(missing) in source.warnings[0]


def test_unsupported_transform_warns_and_skips_the_grid(scene, tmp_path):
    grid = vdb.FloatGrid()
    grid.name = "density"
    grid.copyFromArray(np.ones((2, 2, 2), np.float32))
    grid.transform = vdb.createFrustumTransform((0, 0, 0), (1, 1, 1), 0.5, 2.0)
    vdb.write(str(tmp_path / "frustum.vdb"), grids=[grid])
    source = read(volume_object(scene, tmp_path / "frustum.vdb"))
    assert source.grids == {} and "frustum" in source.warnings[0] and "'density'" in source.warnings[0]


def test_file_sequence_reads_the_frame_blender_resolves(scene, tmp_path):
    for frame in (1, 2, 3):
        grid = vdb.FloatGrid()
        grid.name = "density"
        grid.copyFromArray(np.full((2, 2, 2), float(frame), np.float32))
        vdb.write(str(tmp_path / f"smoke_{frame:04d}.vdb"), grids=[grid])
    ob = volume_object(scene, tmp_path / "smoke_0001.vdb")
    ob.data.is_sequence = True
    ob.data.frame_duration = 3
    for frame in (2, 3):
        scene.frame_set(frame)
        assert read(ob).grids["density"].values.max() == frame
    scene.frame_set(5)                 # past the sequence (Clip): nothing, as Blender shows
    assert read(ob).grids == {}
    scene.frame_set(1)


def test_geometry_nodes_volume_read_without_touching_bpy_data(scene):
    mesh = bpy.data.meshes.new("Emitter")
    ob = bpy.data.objects.new("Emitter", mesh)
    scene.collection.objects.link(ob)
    tree = bpy.data.node_groups.new("VolumeCube", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    cube = tree.nodes.new("GeometryNodeVolumeCube")
    for axis in "XYZ":
        cube.inputs[f"Resolution {axis}"].default_value = 8
    cube.inputs["Density"].default_value = 0.75
    tree.links.new(cube.outputs[0], tree.nodes.new("NodeGroupOutput").inputs[0])
    ob.modifiers.new("Nodes", "NODES").node_group = tree
    ob.location = (3, 0, 0)
    counts = {kind: len(getattr(bpy.data, kind)) for kind in ("objects", "meshes", "volumes", "node_groups")}
    dirty = bpy.data.is_dirty
    exported = export_current()
    ((row, grids, scale, step),) = exported.scene.volumes
    density = grids["density"]
    assert step == pytest.approx(2.0 / 7.0)   # the voxel size: 8 values from -1 to 1 (the Biased option's step)
    assert not [w for w in exported.warnings if "Emitter" in w]
    np.testing.assert_allclose(density.lookup(np.zeros((1, 3), np.float32)), [[0.75]])
    # Blender 5's Volume Cube puts its first and last values on Min and Max (-1 and 1 by default).
    np.testing.assert_allclose(density.bounds(), [[-1, -1, -1], [1, 1, 1]], atol=1e-6)
    # Its boundary is placed where the object is (the padded box around x = 3).
    x = np.asarray(exported.scene.positions)[..., 0]
    assert 1.5 < x.min() < 2.0 and 4.0 < x.max() < 4.5
    assert {kind: len(getattr(bpy.data, kind)) for kind in counts} == counts
    assert bpy.data.is_dirty == dirty


def test_view_layer_without_volumes_exports_none(fields):
    """View Layer > Filter > Volumes off: no volume object is rendered, as in Cycles."""
    assert len(export_current().scene.volumes) == 1
    bpy.context.view_layer.use_volumes = False
    try:
        assert export_current().scene.volumes == ()
    finally:
        bpy.context.view_layer.use_volumes = True


def test_fluid_grid_layout_is_x_fastest_at_cell_centres_of_the_texture_space():
    """FluidDomainSettings' arrays list voxels x fastest; voxel i sits at texture coordinate (i + 0.5) / n
    of the domain mesh's texture space."""
    dims = np.array([4, 3, 2])
    ijk = index_grid(dims).reshape(-1, 3)
    value = 1.0 + ijk[:, 0] + 10.0 * ijk[:, 1] + 100.0 * ijk[:, 2]
    flat = value[np.lexsort((ijk[:, 0], ijk[:, 1], ijk[:, 2]))].astype(np.float32)   # x fastest
    location, size = np.array([0.5, 0.0, -1.0]), np.array([1.0, 2.0, 0.5])
    grid = fluid_grid(flat, dims, 1, location, size, 1e-6)
    centres = location - size + 2 * size * (ijk + 0.5) / dims
    # Closest reads voxel floor(P): at the middle of the cell that starts at a voxel's centre.
    half_voxel = size / dims
    np.testing.assert_allclose(grid.lookup((centres + half_voxel).astype(np.float32), "CLOSEST")[:, 0], value)
    np.testing.assert_allclose(grid.lookup(centres.astype(np.float32), "LINEAR")[:, 0], value, rtol=1e-5)
    np.testing.assert_allclose(grid.bounds(), [centres.min(axis=0), centres.max(axis=0)], atol=1e-6)


def test_fluid_grid_clips_and_crops_and_unpremultiplies_colour():
    dims = np.array([6, 5, 4])
    rgba = np.zeros((4, 5, 6, 4), np.float32)          # (z, y, x, channel): x fastest when flattened
    rgba[1, 2, 3] = [0.4, 0.2, 0.1, 0.5]              # premultiplied by density 0.5
    rgba[2, 2, 3] = [1e-7, 0, 0, 1e-7]                # below the clipping: dropped
    grid = fluid_grid(rgba.ravel(), dims, 4, np.zeros(3), np.ones(3), 1e-6)
    assert grid.shape == (1, 1, 1)
    centre = -1 + 2 * (np.array([3, 2, 1]) + 0.5) / dims
    np.testing.assert_allclose(grid.lookup(centre[None].astype(np.float32), "LINEAR"), [[0.8, 0.4, 0.2, 0.5]],
                               rtol=1e-6)
    assert fluid_grid(np.zeros(dims.prod(), np.float32), dims, 1, np.zeros(3), np.ones(3), 1e-6) is None


def test_smoke_domain_is_a_volume_read_without_warnings(scene):
    """A gas domain is read from FluidDomainSettings. Mantaflow cannot step a simulation in bpy as a module
    (its scripts fail: 'LevelsetGrid' object has no attribute 'setConst'), so the domain is empty: only the
    colour grid is left, Blender's fixed colour (the flows' colour, black without flows) with alpha 1 in
    every cell, so its active box, and the boundary, is the whole domain, as in Cycles."""
    import bmesh
    mesh = bpy.data.meshes.new("Domain")
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bm.to_mesh(mesh)
    bm.free()
    ob = bpy.data.objects.new("Domain", mesh)
    scene.collection.objects.link(ob)
    fluid = ob.modifiers.new("Fluid", "FLUID")
    fluid.fluid_type = "DOMAIN"
    fluid.domain_settings.domain_type = "GAS"
    fluid.domain_settings.resolution_max = 12
    try:
        evaluated = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
        assert is_volume(evaluated)
        assert len(evaluated.modifiers["Fluid"].domain_settings.density_grid) == 12 ** 3
        source = read(ob)
        assert source.kind == "FLUID" and list(source.grids) == ["color"] and source.warnings == []
        colour = source.grids["color"]
        assert colour.shape == (12, 12, 12)
        np.testing.assert_allclose(colour.lookup(np.zeros((1, 3), np.float32)), [[0, 0, 0, 1]])
        # Cell centres from -1 + 1/12 to 1 - 1/12 (texture space of the 2 m cube), one voxel more per side.
        np.testing.assert_allclose(source.vertices.min(axis=0), [-1 - 1 / 12] * 3, atol=1e-6)
        np.testing.assert_allclose(source.vertices.max(axis=0), [1 + 1 / 12] * 3, atol=1e-6)
    finally:
        # A domain left alive aborts the process at exit (Mantaflow: "can't clean grid cache").
        bpy.data.objects.remove(ob)
        bpy.context.evaluated_depsgraph_get()


def test_voxel_grid_rejects_bad_shapes_and_interpolations():
    with pytest.raises(ValueError):
        VoxelGrid(np.zeros((2, 2, 2, 2)), np.eye(4))
    grid = VoxelGrid(np.ones((2, 2, 2)), np.eye(4))
    assert grid.channels == 1
    with pytest.raises(ValueError):
        grid.lookup(np.zeros((1, 3), np.float32), "SMART")
    assert PADDING == {"CLOSEST": 0, "LINEAR": 1, "CUBIC": 2}
