"""Volumes with voxel grids: what Cycles renders from Volume objects and from smoke (gas) fluid domains,
read into kernels.media.grid.VoxelGrid records (Cycles' blender/volume.cpp: sync_volume_object and
sync_smoke_volume).

    source = read_volume(ob_eval, frame)      # engine/export/geometry.py reads each rendered volume so
    warnings.extend(source.warnings)
    density = source.grids.get("density")     # a VoxelGrid, or None

Volume objects. Blender evaluates the volume (the frame of a file sequence, modifiers, geometry nodes) and
Cycles reads the evaluated grids. Ember reads them through the `openvdb` module that Blender ships
(openvdb_module): from the file Blender resolved for the frame when the object has no modifiers, else from a
temporary .vdb that VolumeGrids.save() writes from the evaluated grids (geometry-nodes volumes, which are
never in a file). Neither touches bpy.data or the .blend.

Smoke domains. A mesh object whose Fluid modifier is a gas domain: density, color (premultiplied RGBA),
flame, heat, temperature and velocity as FluidDomainSettings gives them, flat arrays with x fastest
(OpenVDB's Dense LayoutXYZ, which Cycles' BlenderSmokeLoader hands them to), voxel centres spread over the
domain mesh's texture space.

Not read: velocity as motion (volume motion blur), the scalar velocity_x/y/z grids Cycles merges for it, and
the render precision (Cycles quantises to half floats by default; Ember keeps full floats).
"""
from __future__ import annotations

import glob
import importlib.machinery
import importlib.util
import os
import sys
import tempfile
from dataclasses import dataclass, field

import bpy
import numpy as np

from ...kernels.media.grid import PADDING, VoxelGrid

# Cycles' attribute names of a smoke domain's grids, the FluidDomainSettings array of each, its channels, and
# whether it keeps the base resolution when noise upsamples the rest (blender/volume.cpp, BlenderSmokeLoader).
FLUID_GRIDS = (("density", "density_grid", 1, False), ("color", "color_grid", 4, False),
               ("flame", "flame_grid", 1, False), ("heat", "heat_grid", 1, True),
               ("temperature", "temperature_grid", 1, False), ("velocity", "velocity_grid", 3, True))
# A sparse grid becomes dense over its active bounding box; past this many voxels it is dropped with a warning.
MAX_DENSE_VOXELS = 1 << 29
# OpenVDB value types by channel count; other types (points, masks, strings) are not volumes Cycles renders.
_SCALAR_TYPES = {"float", "double", "int32", "int64", "bool"}
_VECTOR_TYPES = {"vec3s", "vec3d", "vec3i"}

_openvdb = None


@dataclass
class VolumeSource:
    """One rendered volume: a Volume object or a smoke domain, placed by one depsgraph instance.

    grids : Cycles' attribute name ('density', 'color', ...; a VDB file's own grid names) -> VoxelGrid.
        Instances of the same data share the grid records.
    vertices : (V, 3) float32, triangles : (T, 3) int32: the boundary to trace, a closed box in object space
        around the active voxels of all grids, grown by the lookups' padding (Cycles' VolumeMeshBuilder
        without ray marching), outward facing; empty when no grid has an active voxel.
    world_from_object : (4, 4) float64.
    step_size, object_space : Volume > Render settings (step size for the biased ray marcher, in object
        or world units); 0 and False for smoke domains.
    warnings : what was dropped, one line each.
    """
    name: str
    kind: str                                    # 'VOLUME' or 'FLUID'
    grids: dict[str, VoxelGrid]
    vertices: np.ndarray
    triangles: np.ndarray
    world_from_object: np.ndarray
    step_size: float = 0.0
    object_space: bool = False
    warnings: list[str] = field(default_factory=list)


# ---------------------------------------------------------------- the openvdb module
def openvdb_module():
    """Blender's own `openvdb` Python module, or None. Inside Blender it is on sys.path; bpy as a Python
    module carries it in its bundled Python's site-packages (bpy/<version>/python/lib/python3.x/
    site-packages), which is not on sys.path and must not be (its other packages would shadow the
    environment's), so it is loaded from there by file, with this interpreter's extension suffixes."""
    global _openvdb
    if _openvdb is None:
        _openvdb = sys.modules.get("openvdb") or _bundled_openvdb() or _importable_openvdb()
    return _openvdb or None


def _bundled_openvdb():
    root = bpy.utils.system_resource("PYTHON")
    if not root:
        return None
    folders = (glob.glob(os.path.join(root, "lib*", "site-packages"))
               + glob.glob(os.path.join(root, "lib*", "python3*", "site-packages")))
    for folder in folders:
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = os.path.join(folder, "openvdb" + suffix)
            if os.path.isfile(path):
                spec = importlib.util.spec_from_file_location("openvdb", path)
                module = importlib.util.module_from_spec(spec)
                sys.modules["openvdb"] = module
                try:
                    spec.loader.exec_module(module)
                except ImportError:
                    del sys.modules["openvdb"]
                    continue
                return module
    return None


def _importable_openvdb():
    try:
        import openvdb
    except ImportError:
        return False          # looked for and absent: remembered, not searched again
    return openvdb


# ---------------------------------------------------------------- the depsgraph
def fluid_gas_domain(ob):
    """The FluidDomainSettings of the object's gas domain Fluid modifier, or None (Cycles'
    object_fluid_gas_domain_find: the first such modifier, whatever its visibility)."""
    for modifier in getattr(ob, "modifiers", ()):
        if modifier.type == "FLUID" and modifier.fluid_type == "DOMAIN" \
                and modifier.domain_settings.domain_type == "GAS":
            return modifier.domain_settings
    return None


def is_volume(ob) -> bool:
    """Whether Cycles renders the evaluated object as a volume: a Volume object or a smoke domain."""
    return ob.type == "VOLUME" or (ob.type == "MESH" and fluid_gas_domain(ob) is not None)


def read_volume(ob, frame: int, interpolation: str = "LINEAR", grid_names=None) -> VolumeSource:
    """The grids and boundary of one evaluated volume object (is_volume) at the scene frame `frame`. Broken
    or unsupported input becomes a warning, never an exception."""
    warnings: list[str] = []
    step_size, object_space = 0.0, False
    try:
        if ob.type == "VOLUME":
            kind = "VOLUME"
            grids = read_volume_grids(ob, warnings)
            step_size = float(ob.data.render.step_size)
            object_space = ob.data.render.space == "OBJECT"
        else:
            kind = "FLUID"
            grids = read_fluid_grids(ob, fluid_gas_domain(ob), frame, warnings)
    except Exception as error:   # a volume that cannot be read is dropped, the render goes on
        kind, grids = ob.type, {}
        warnings.append(f"Object '{ob.name}': its volume cannot be read ({type(error).__name__}: {error}), "
                        f"not rendered")
    if grid_names is not None:
        grids = {name: grid for name, grid in grids.items() if name in grid_names}
    vertices, triangles = boundary_mesh(list(grids.values()), PADDING[interpolation])
    return VolumeSource(ob.name, kind, grids, vertices, triangles, np.array(ob.matrix_world, dtype=np.float64),
                        step_size, object_space, warnings)


# ---------------------------------------------------------------- Volume objects
def read_volume_grids(ob, warnings: list[str]) -> dict[str, VoxelGrid]:
    """The evaluated Volume's grids by name (and the velocity grid the volume names also as 'velocity')."""
    volume = ob.data
    grids = volume.grids
    if grids.error_message:
        path = bpy.path.abspath(volume.filepath, library=volume.original.library)
        warnings.append(f"Object '{ob.name}': volume file '{path}' cannot be read ({grids.error_message}), "
                        f"not rendered")
        return {}
    if len(grids) == 0:
        return {}
    vdb = openvdb_module()
    if vdb is None:
        warnings.append(f"Object '{ob.name}': Blender's openvdb module was not found, volume not rendered")
        return {}
    clipping = float(volume.render.clipping)
    direct = grids.frame_filepath and not ob.modifiers and volume.packed_file is None
    path = bpy.path.abspath(grids.frame_filepath, library=volume.original.library) if direct else ""
    if path and os.path.isfile(path):
        out = read_vdb_file(vdb, path, clipping, ob.name, warnings)
    else:
        # Geometry nodes, modifiers or a packed file: the evaluated grids, written to a temporary file.
        with tempfile.TemporaryDirectory(prefix="ember-volume-", ignore_cleanup_errors=True) as folder:
            path = os.path.join(folder, "grids.vdb")
            if not grids.save(path):
                warnings.append(f"Object '{ob.name}': its evaluated volume grids could not be written for "
                                f"reading, not rendered")
                return {}
            out = read_vdb_file(vdb, path, clipping, ob.name, warnings)
    if volume.velocity_grid and volume.velocity_grid in out and "velocity" not in out:
        out["velocity"] = out[volume.velocity_grid]
    return out


def read_vdb_file(vdb, path: str, clipping: float, owner: str, warnings: list[str]) -> dict[str, VoxelGrid]:
    """Every grid of a .vdb file that Cycles renders, by name."""
    out = {}
    vdb_grids, _ = vdb.readAll(path)
    for vdb_grid in vdb_grids:
        name = vdb_grid.name
        try:
            grid = voxel_grid_from_vdb(vdb_grid, clipping)
        except ValueError as reason:
            warnings.append(f"Object '{owner}': volume grid '{name}' {reason}, not rendered")
            continue
        if grid is not None:
            out[name] = grid
    return out


def voxel_grid_from_vdb(vdb_grid, clipping: float) -> VoxelGrid | None:
    """A VoxelGrid over the grid's active bounding box, or None for a grid without active voxels (Cycles'
    NANOVDB_EMPTY) or none above the clipping; ValueError says why a grid cannot be read. Voxels at or below `clipping` (Volume >
    Render > Clipping) are deactivated as Cycles does (openvdb::tools::deactivate): they keep their values
    but leave the active box the boundary encloses."""
    kind = vdb_grid.valueTypeName
    if kind not in _SCALAR_TYPES | _VECTOR_TYPES:
        raise ValueError(f"holds values of type '{kind}', which volumes do not render")
    if not vdb_grid.transform.isLinear:
        raise ValueError("has a non-linear (frustum) transform, which Ember does not support")
    if vdb_grid.activeVoxelCount() == 0:
        return None
    lo, hi = (np.asarray(corner, dtype=np.int64) for corner in vdb_grid.evalActiveVoxelBoundingBox())
    dims = hi - lo + 1
    if int(np.prod(dims)) > MAX_DENSE_VOXELS:
        raise ValueError(f"spans {dims[0]} x {dims[1]} x {dims[2]} voxels, more than Ember reads densely")
    channels = 3 if kind in _VECTOR_TYPES else 1
    dtype = {"double": np.float64, "vec3d": np.float64, "int32": np.int32, "int64": np.int64, "vec3i": np.int32,
             "bool": np.bool_}.get(kind, np.float32)
    dense = np.empty(tuple(dims) + ((3,) if channels == 3 else ()), dtype=dtype)
    vdb_grid.copyToArray(dense, ijk=tuple(int(c) for c in lo))
    values = dense.astype(np.float32).reshape(tuple(dims) + (channels,))
    background = np.asarray(vdb_grid.background, dtype=np.float32)
    transform = vdb_grid.transform
    # The affine index -> object map from four points (Cycles takes the grid's affine map, image_vdb.cpp).
    origin, *axes = (np.asarray(transform.indexToWorld(tuple(float(c) for c in point)), dtype=np.float64)
                     for point in (lo, lo + (1, 0, 0), lo + (0, 1, 0), lo + (0, 0, 1)))
    index_to_object = np.eye(4)
    index_to_object[:3, :3] = np.stack([axis - origin for axis in axes], axis=1)
    index_to_object[:3, 3] = origin
    box = active_box(values, clipping)
    # Nothing above the clipping: Cycles keeps the values but no active voxel, so the grid adds nothing to
    # the boundary; it is dropped (its lookups would give at most `clipping`).
    return None if box is None else VoxelGrid(values, index_to_object, background, box)


def active_box(values: np.ndarray, clipping: float):
    """Inclusive index bounds of the voxels with some |channel| > clipping, the whole block when clipping is
    0 (every voxel of the block kept), or None when none passes."""
    if clipping <= 0:
        return ((0, 0, 0), tuple(n - 1 for n in values.shape[:3]))
    above = np.abs(values).max(axis=3) > clipping
    if not above.any():
        return None
    spans = [np.flatnonzero(above.any(axis=tuple(a for a in range(3) if a != axis))) for axis in range(3)]
    return tuple(int(span[0]) for span in spans), tuple(int(span[-1]) for span in spans)


# ---------------------------------------------------------------- smoke domains
def read_fluid_grids(ob, domain, frame: int, warnings: list[str]) -> dict[str, VoxelGrid]:
    """The smoke domain's grids at `frame` (none outside the cache's frame range, as Cycles)."""
    if not domain.cache_frame_start <= frame <= domain.cache_frame_end:
        return {}
    resolution = np.array(domain.domain_resolution, dtype=np.int64)
    amplify = int(domain.noise_scale) if domain.use_noise else 1
    mesh = ob.data
    location = np.array(mesh.texspace_location, dtype=np.float64)
    size = np.array(mesh.texspace_size, dtype=np.float64)
    out = {}
    for name, prop, channels, base_resolution in FLUID_GRIDS:
        dims = resolution if base_resolution else resolution * amplify
        array = getattr(domain, prop)
        if len(array) != int(np.prod(dims)) * channels:
            if len(array):
                warnings.append(f"Object '{ob.name}': smoke grid '{name}' has {len(array)} values, not the "
                                f"domain's {' x '.join(map(str, dims))} x {channels}; skipped")
            continue
        flat = np.empty(len(array), dtype=np.float32)
        array.foreach_get(flat)
        grid = fluid_grid(flat, dims, channels, location, size, float(domain.clipping))
        if grid is not None:
            out[name] = grid
    return out


def fluid_grid(flat: np.ndarray, dims, channels: int, location, size, clipping: float) -> VoxelGrid | None:
    """One smoke grid: `flat` holds dims[0] x dims[1] x dims[2] voxels of `channels` values, x fastest.
    Mantaflow stores values at cell centres: voxel i sits at texture coordinate (i + 0.5) / dims of the
    domain mesh's texture space (location +- size), as Cycles does from Blender 5.2 (blender/volume.cpp,
    "Mantaflow stores values at cell centers"; 5.0 offsets them by 1 / dims object units instead, which is
    the same for a texture space of size 1, the default cube's). Voxels whose every |channel| is at or below
    `clipping` are dropped to the background 0 (openvdb::tools::copyFromDense with that tolerance); the
    block is cropped to the rest, which loses nothing. None when no voxel is left."""
    nx, ny, nz = (int(n) for n in dims)
    values = flat.reshape(nz, ny, nx, channels).transpose(2, 1, 0, 3)
    values = np.where(np.abs(values).max(axis=3, keepdims=True) > clipping, values, np.float32(0))
    box = active_box(values, max(clipping, 0.0) or np.finfo(np.float32).tiny)
    if box is None:
        return None
    (i0, j0, k0), (i1, j1, k1) = box
    voxel = 2.0 * np.asarray(size, dtype=np.float64) / (nx, ny, nz)
    index_to_object = np.diag([*voxel, 1.0])
    index_to_object[:3, 3] = np.asarray(location) - size + voxel * (0.5 + np.array([i0, j0, k0]))
    return VoxelGrid(values[i0:i1 + 1, j0:j1 + 1, k0:k1 + 1], index_to_object, 0.0)


# ---------------------------------------------------------------- the boundary
def boundary_mesh(grids: list[VoxelGrid], padding: int) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float32 vertices and (T, 3) int32 outward triangles of the box, in the index space of the first
    grid, around every grid's active box grown by `padding` voxels (Cycles merges the
    grids' topologies in the first grid's index space, dilates them and takes their bounding box)."""
    if not grids:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32)
    reference = grids[0]
    corners = np.concatenate([grid.box_corners(padding) for grid in grids])
    in_reference = corners @ reference.object_to_index[:3, :3].T + reference.object_to_index[:3, 3]
    lo, hi = in_reference.min(axis=0), in_reference.max(axis=0)
    box = np.array([[(hi if (n >> a) & 1 else lo)[a] for a in range(3)] for n in range(8)])
    vertices = box @ reference.index_to_object[:3, :3].T + reference.index_to_object[:3, 3]
    # Two triangles per face, corners numbered by bits (x, y, z), wound counter-clockwise seen from outside
    # the index-space box; a mirroring transform (negative determinant) turns them inside out, so flip.
    triangles = np.array([[0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5], [0, 1, 5], [0, 5, 4],
                          [2, 6, 7], [2, 7, 3], [0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6]], dtype=np.int32)
    if np.linalg.det(reference.index_to_object[:3, :3]) < 0:
        triangles = triangles[:, ::-1].copy()
    return vertices.astype(np.float32), triangles
