"""Embree's own C API through ctypes: indexed triangle meshes shared with NumPy, two-level scenes
(instances of meshes), and ray queries 16 at a time.

embreex (the project's Embree binding) builds flat triangle scenes and traces one ray per C call from its
Cython loop. It copies every triangle's three corners into Embree and cannot instance a mesh. This module
reaches the same Embree library that embreex ships (no new dependency) and uses what its Python binding
leaves out:

- rtcSetSharedGeometryBuffer: Embree reads vertices and indices straight from NumPy arrays (kept alive by
  the Mesh object), no copy: a commit skips embreex's copy of three corners per triangle and its memory.
- RTC_GEOMETRY_TYPE_INSTANCE: a mesh's BVH is built once and placed by any number of 3x4 transforms,
  Cycles' and Embree's two-level layout; the top level is tiny, so memory grows with unique geometry.
  Instances move without rebuilding any mesh BVH (Scene.set_transforms: rtcGetGeometry,
  rtcSetGeometryTransform, rtcCommitGeometry, then rtcCommitScene on the top level): the viewport's
  moved objects.
- rtcSetSceneBuildQuality / rtcSetGeometryBuildQuality: a big mesh's first BVH is built LOW (Embree's
  Morton builder, several times faster) and a MEDIUM one later (kernels.accel.Accel.refine), whose build
  rtcSetSceneProgressMonitorFunction can cancel.
- RTC_GEOMETRY_TYPE_SPHERE_POINT and the curve types Cycles uses (ROUND_CATMULL_ROM, FLAT_CATMULL_ROM,
  ROUND_LINEAR): Shape reads their (V, 4) float32 x, y, z, radius vertices and segment indices in place, as a
  geometry of the top level (world space) or of a ShapeScene of its own (instanced); hits on them report their
  geometry (Scene.intersect's geometry=True).
- rtcIntersect16 / rtcOccluded16 on packets laid out by NumPy (Embree's SOA RTCRayHit16): one ctypes
  call per 16 rays, with the GIL released while Embree traces. It reports which instance a ray hit, which
  embreex's loop does not, and finds the same hits and distances bit for bit; but packing the rays and one
  Python-level call per 16 rays cost more than embreex's Cython loop, most for short shadow rays.

So every query that needs no instance id (all queries of a scene without instances, and shadow rays of
any scene) runs through embreex's Cython loop on the scene built here: `Scene.embreex()` hands embreex an
EmbreeScene whose scene handle is this one. EmbreeScene keeps its handle in a private C field; its offset
is found from the public field declared right after it and checked by tracing a ray before use, and
anything unexpected falls back to the packets.

Struct layouts and enum values are Embree 4's public headers (rtcore_ray.h, rtcore_common.h,
rtcore_geometry.h). The library is found next to embreex: `embreex.libs/` (Linux and Windows wheels) or
`embreex/.dylibs/` (macOS wheels). Only the Linux wheel could be run where this was written.
"""
from __future__ import annotations

import ctypes
import glob
import os
import threading

import numpy as np

# Enum values of Embree 4's headers.
_GEOMETRY_TRIANGLE, _GEOMETRY_INSTANCE = 0, 121
# RTCGeometryType of the curves and points Cycles traces (intern/cycles/bvh/embree.cpp, add_curves, add_points).
CURVE_GEOMETRY = {"ROUND": 58, "RIBBON": 59, "LINEAR": 16}   # ROUND_CATMULL_ROM, FLAT_CATMULL_ROM, ROUND_LINEAR
SPHERE_POINT = 50
_BUFFER_INDEX, _BUFFER_VERTEX = 0, 1
_FORMAT_UINT, _FORMAT_UINT3, _FORMAT_FLOAT3, _FORMAT_FLOAT4 = 0x5001, 0x5003, 0x9003, 0x9004
_FORMAT_FLOAT3X4_ROW_MAJOR = 0x9134
_SCENE_FLAG_ROBUST = 1 << 2
_ERROR_CANCELLED = 6
# RTCBuildQuality: LOW is Embree's quick (Morton) builder, MEDIUM its binned SAH builder (Cycles' setting for
# final renders without spatial splits; its viewport builds LOW).
BUILD_QUALITY = {"low": 0, "medium": 1, "high": 2}
INVALID = 0xFFFFFFFF
# bool RTCProgressMonitorFunction(void* ptr, double n): Embree calls it during a build; False cancels it.
_PROGRESS = ctypes.CFUNCTYPE(ctypes.c_bool, ctypes.c_void_p, ctypes.c_double)

# RTCRayHit16, one row of 16 lanes per field: the ray (org xyz, tnear, dir xyz, time, tfar, mask, id, flags),
# then the hit (Ng xyz, u, v, primID, geomID, instID[levels], instPrimID[levels]). Rows past instID are
# room for the instancing levels and instance-array ids a build may add; Embree never reads them here.
_ORG, _TNEAR, _DIR, _TIME, _TFAR, _MASK, _ID, _FLAGS = 0, 3, 4, 7, 8, 9, 10, 11
_NG, _U, _V, _PRIM, _GEOM, _INST = 12, 15, 16, 17, 18, 19
_HIT_ROWS = 32          # RTCRayHit16 with headroom: 32 x 64 bytes per packet
_RAY_ROWS = 12          # RTCRay16
_LANES = 16
_ALIGN = 64             # Embree requires 64-byte aligned packets and valid masks

_lock = threading.Lock()
_lib = None


class EmbreeError(RuntimeError):
    """Embree could not be loaded, or refused a scene (its device error code in the message)."""


class BuildCancelled(EmbreeError):
    """A Scene's build was stopped by its cancel event."""


def _library_paths() -> list[str]:
    import embreex  # noqa: F401  (loads the library and, on Windows, registers its DLL directory)
    package = os.path.dirname(os.path.abspath(embreex.__file__))
    found = []
    for folder in (os.path.join(package, ".dylibs"), os.path.join(os.path.dirname(package), "embreex.libs"),
                   package):
        for pattern in ("libembree4*.so*", "libembree4*.dylib", "embree4*.dll"):
            found.extend(sorted(glob.glob(os.path.join(folder, pattern))))
    return found


def library() -> ctypes.CDLL:
    """The Embree 4 library embreex ships, with the signatures this module uses."""
    global _lib
    with _lock:
        if _lib is None:
            paths = _library_paths()
            if not paths:
                raise EmbreeError("Embree's library was not found next to embreex")
            _lib = _declare(ctypes.CDLL(paths[0]))
        return _lib


def _declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    vp, uint, size, cint = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t, ctypes.c_int
    signatures = {
        "rtcNewDevice": (vp, [ctypes.c_char_p]),
        "rtcReleaseDevice": (None, [vp]),
        "rtcGetDeviceError": (cint, [vp]),
        "rtcNewScene": (vp, [vp]),
        "rtcSetSceneFlags": (None, [vp, cint]),
        "rtcSetSceneBuildQuality": (None, [vp, cint]),
        "rtcSetSceneProgressMonitorFunction": (None, [vp, _PROGRESS, vp]),
        "rtcSetGeometryBuildQuality": (None, [vp, cint]),
        "rtcSetGeometryTessellationRate": (None, [vp, ctypes.c_float]),
        "rtcSetGeometryTimeStepCount": (None, [vp, uint]),
        "rtcSetGeometryTransformQuaternion": (None, [vp, uint, vp]),
        "rtcCommitScene": (None, [vp]),
        "rtcReleaseScene": (None, [vp]),
        "rtcRetainScene": (None, [vp]),
        "rtcNewGeometry": (vp, [vp, cint]),
        "rtcSetSharedGeometryBuffer": (None, [vp, cint, uint, cint, vp, size, size, size]),
        "rtcSetGeometryInstancedScene": (None, [vp, vp]),
        "rtcSetGeometryTransform": (None, [vp, uint, cint, vp]),
        "rtcCommitGeometry": (None, [vp]),
        "rtcAttachGeometryByID": (None, [vp, vp, uint]),
        "rtcReleaseGeometry": (None, [vp]),
        "rtcGetGeometry": (vp, [vp, uint]),
        "rtcIntersect16": (None, [vp, vp, vp, vp]),
        "rtcOccluded16": (None, [vp, vp, vp, vp]),
    }
    for name, (restype, argtypes) in signatures.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = restype, argtypes
    return lib


def aligned_empty(shape, dtype) -> np.ndarray:
    """An uninitialised array whose data starts on a 64-byte boundary."""
    dtype = np.dtype(dtype)
    count = int(np.prod(shape))
    raw = np.empty(count * dtype.itemsize + _ALIGN, np.uint8)
    offset = -raw.ctypes.data % _ALIGN
    return raw[offset:offset + count * dtype.itemsize].view(dtype).reshape(shape)


class Device:
    """An Embree device; scenes and meshes keep theirs alive."""

    def __init__(self):
        self.lib = library()
        self.handle = self.lib.rtcNewDevice(None)
        if not self.handle:
            raise EmbreeError("Embree could not create a device")

    def check(self, what: str) -> None:
        code = self.lib.rtcGetDeviceError(self.handle)
        if code == _ERROR_CANCELLED:
            raise BuildCancelled(f"the build of {what} was cancelled")
        if code:
            raise EmbreeError(f"Embree refused {what} (error {code})")

    def __del__(self):
        if getattr(self, "handle", None):
            self.lib.rtcReleaseDevice(self.handle)
            self.handle = None


def _triangle_geometry(device: Device, vertices: np.ndarray, indices: np.ndarray, quality: str = "medium"):
    """A committed triangle geometry reading vertices (V + 1, 3) float32 (the last row is padding: Embree
    reads vertices 16 bytes at a time) and indices (T, 3) uint32 in place."""
    lib = device.lib
    geom = lib.rtcNewGeometry(device.handle, _GEOMETRY_TRIANGLE)
    lib.rtcSetGeometryBuildQuality(geom, BUILD_QUALITY[quality])
    lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3, vertices.ctypes.data, 0, 12,
                                   len(vertices) - 1)
    lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_INDEX, 0, _FORMAT_UINT3, indices.ctypes.data, 0, 12,
                                   len(indices))
    lib.rtcCommitGeometry(geom)
    return geom


def padded_vertices(vertices: np.ndarray) -> np.ndarray:
    """(V + 1, 3) float32 vertices Embree can read in place: the array itself when it is a contiguous
    float32 view with at least one more row of its buffer after it (kernels.scene.padded_triangles
    allocates so), else a copy with a zero padding row."""
    if vertices.dtype == np.float32 and vertices.flags.c_contiguous and vertices.ndim == 2:
        base = vertices
        while isinstance(base.base, np.ndarray):
            base = base.base
        end = vertices.ctypes.data + vertices.nbytes
        if base is not vertices and base.flags.c_contiguous and base.ctypes.data + base.nbytes >= end + 12:
            return np.ndarray((len(vertices) + 1, 3), np.float32, buffer=base,
                              offset=vertices.ctypes.data - base.ctypes.data)
    out = np.zeros((len(vertices) + 1, 3), np.float32)
    out[:-1] = vertices
    return out


def flat_indices(triangle_count: int) -> np.ndarray:
    """(T, 3) uint32 indices of triangles stored as consecutive corner triples."""
    return np.arange(3 * triangle_count, dtype=np.uint32).reshape(-1, 3)


class Triangles:
    """Triangles in the layouts Embree reads in place, with no BVH of their own: the top level's plain
    geometry (Scene's `plain`), whose BVH is the top level's.

    vertices : (V, 3) float32; indices : (T, 3) integer corners. Both are copied once into the layouts
    Embree reads in place (or used as they are when already padded / uint32 contiguous)."""

    def __init__(self, vertices: np.ndarray, indices: np.ndarray | None = None):
        self.vertices = padded_vertices(np.asarray(vertices, np.float32).reshape(-1, 3))
        v = len(self.vertices) - 1
        self.indices = flat_indices(v // 3) if indices is None else \
            np.ascontiguousarray(np.asarray(indices).reshape(-1, 3), np.uint32)

    @property
    def triangle_count(self) -> int:
        return len(self.indices)


class Mesh(Triangles):
    """One triangle mesh in its own Embree scene (a bottom-level BVH), to be instanced."""

    def __init__(self, device: Device, vertices: np.ndarray, indices: np.ndarray | None = None):
        super().__init__(vertices, indices)
        self.device = device
        lib = device.lib
        self.handle = lib.rtcNewScene(device.handle)
        lib.rtcSetSceneFlags(self.handle, _SCENE_FLAG_ROBUST)
        if len(self.indices):
            geom = _triangle_geometry(device, self.vertices, self.indices)
            lib.rtcAttachGeometryByID(self.handle, geom, 0)
            lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(self.handle)
        device.check("a triangle mesh")

    def __del__(self):
        if getattr(self, "handle", None):
            self.device.lib.rtcReleaseScene(self.handle)
            self.handle = None


class Shape:
    """Curves or points in the layouts Embree reads in place, with no BVH of their own: a geometry of the top
    level (Scene's `shapes`) or of a ShapeScene.

    kind : an RTCGeometryType (CURVE_GEOMETRY's, SPHERE_POINT); vertices : (V, 4) float32 x, y, z, radius;
    indices : (S,) uint32, each curve segment's first control vertex (None for points); tessellation : Embree's
    tessellation rate of curves (Cycles': Subdivisions + 1). steps : None, or (T, V, 4) float32 vertices at T >= 2
    times evenly spread over [0, 1] (motion blur): Embree's time steps, one vertex buffer each, interpolated
    linearly at each ray's time (as Cycles' add_curves and add_points give them, intern/cycles/bvh/embree.cpp);
    vertices is then not read by Embree."""

    def __init__(self, kind: int, vertices: np.ndarray, indices: np.ndarray | None = None,
                 tessellation: float | None = None, steps: np.ndarray | None = None):
        self.kind = kind
        self.vertices = np.ascontiguousarray(vertices, np.float32).reshape(-1, 4)
        self.steps = None if steps is None else np.ascontiguousarray(steps, np.float32).reshape(
            len(steps), -1, 4)
        self.indices = None if indices is None else np.ascontiguousarray(indices, np.uint32).reshape(-1)
        self.tessellation = tessellation

    @property
    def primitive_count(self) -> int:
        return len(self.vertices) if self.indices is None else len(self.indices)

    def attach(self, device: Device, scene_handle, geom_id: int, quality: str = "medium") -> None:
        """A committed geometry of these buffers (read in place), attached to a scene as geom_id."""
        lib = device.lib
        geom = lib.rtcNewGeometry(device.handle, self.kind)
        lib.rtcSetGeometryBuildQuality(geom, BUILD_QUALITY[quality])
        if self.tessellation is not None:
            lib.rtcSetGeometryTessellationRate(geom, float(self.tessellation))
        if self.indices is not None:
            lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_INDEX, 0, _FORMAT_UINT, self.indices.ctypes.data, 0, 4,
                                           len(self.indices))
        if self.steps is None:
            lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_VERTEX, 0, _FORMAT_FLOAT4, self.vertices.ctypes.data, 0,
                                           16, len(self.vertices))
        else:
            lib.rtcSetGeometryTimeStepCount(geom, len(self.steps))
            for step, vertices in enumerate(self.steps):
                lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_VERTEX, step, _FORMAT_FLOAT4, vertices.ctypes.data, 0,
                                               16, len(vertices))
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometryByID(scene_handle, geom, geom_id)
        lib.rtcReleaseGeometry(geom)


class ShapeScene:
    """One Shape in its own Embree scene (a bottom-level BVH), to be instanced like a Mesh."""

    def __init__(self, device: Device, shape: Shape):
        self.device, self.shape = device, shape
        self.handle = device.lib.rtcNewScene(device.handle)
        device.lib.rtcSetSceneFlags(self.handle, _SCENE_FLAG_ROBUST)
        if shape.primitive_count:
            shape.attach(device, self.handle, 0)
        device.lib.rtcCommitScene(self.handle)
        device.check("curves or points")

    def __del__(self):
        if getattr(self, "handle", None):
            self.device.lib.rtcReleaseScene(self.handle)
            self.handle = None


class Scene:
    """The top level: one mesh used as it is (geometry 0, world-space triangles), instances of other
    meshes (or ShapeScenes) placed by (3, 4) world_from_object transforms (geometries 1 .. K), and curves and
    points in world space (geometries K + 1 ..).

    Queries report each hit's instance (-1 for the plain mesh) and the triangle within its mesh."""

    def __init__(self, device: Device, plain: Triangles | None = None, instances=(), quality: str = "medium",
                 cancel: threading.Event | None = None, shapes=()):
        """plain: the triangles used as they are, in the top level's own BVH (a Mesh's BVH is not used);
        instances: iterable of (Mesh or ShapeScene, (3, 4) or (4, 4) world_from_object[, motion]); motion, when
        given and not None, is a kernels.motion.Decomposed of S >= 2 steps over the shutter: the instance then moves,
        Embree interpolating its steps at each ray's time (quaternion_steps); shapes: Shapes in world space (curves,
        points), geometries K + 1, K + 2, ... of the top level.
        quality: the top level's BUILD_QUALITY ("low" builds several times faster, traces somewhat slower;
        hits are the same either way: only the tree differs, not the triangle test).
        cancel: an event that stops the build when set (Embree's progress monitor), and BuildCancelled is
        raised."""
        self.device = device
        self.quality = quality
        lib = device.lib
        self.handle = lib.rtcNewScene(device.handle)
        lib.rtcSetSceneFlags(self.handle, _SCENE_FLAG_ROBUST)
        lib.rtcSetSceneBuildQuality(self.handle, BUILD_QUALITY[quality])
        if cancel is not None:
            monitor = _PROGRESS(lambda _ptr, _n: not cancel.is_set())
            lib.rtcSetSceneProgressMonitorFunction(self.handle, monitor, None)
        self._meshes = []      # keeps every instanced mesh (and its buffers) alive
        self.plain = plain
        if plain is not None and plain.triangle_count:
            geom = _triangle_geometry(device, plain.vertices, plain.indices, quality)
            lib.rtcAttachGeometryByID(self.handle, geom, 0)
            lib.rtcReleaseGeometry(geom)
        placed = list(instances)
        # The transforms as Embree holds them, (K, 3, 4) float32: set_transforms compares against them.
        self._transforms = _transforms([entry[1] for entry in placed])
        for k, (mesh, *rest) in enumerate(placed):
            geom = lib.rtcNewGeometry(device.handle, _GEOMETRY_INSTANCE)
            lib.rtcSetGeometryInstancedScene(geom, mesh.handle)
            steps = quaternion_steps(rest[1]) if len(rest) > 1 and rest[1] is not None else None
            if steps is None:
                lib.rtcSetGeometryTransform(geom, 0, _FORMAT_FLOAT3X4_ROW_MAJOR, self._transforms[k].ctypes.data)
            else:
                lib.rtcSetGeometryTimeStepCount(geom, len(steps))
                for step in range(len(steps)):
                    lib.rtcSetGeometryTransformQuaternion(geom, step, steps[step].ctypes.data)
            lib.rtcCommitGeometry(geom)
            lib.rtcAttachGeometryByID(self.handle, geom, 1 + k)
            lib.rtcReleaseGeometry(geom)
            self._meshes.append(mesh)
        self.instance_count = len(placed)
        self.shapes = tuple(shapes)   # kept alive: Embree reads their buffers in place
        for j, shape in enumerate(self.shapes):
            if shape.primitive_count:
                shape.attach(device, self.handle, 1 + len(placed) + j, quality)
        lib.rtcCommitScene(self.handle)
        if cancel is not None:
            lib.rtcSetSceneProgressMonitorFunction(self.handle, _PROGRESS(), None)
        device.check("the scene")
        self._valid_all = aligned_empty((_LANES,), np.int32)
        self._valid_all[:] = -1

    def __del__(self):
        if getattr(self, "handle", None):
            self.device.lib.rtcReleaseScene(self.handle)
            self.handle = None

    def set_transforms(self, world_from_object) -> int:
        """Move the instances to (K, 3, 4) or (K, 4, 4) world_from_object, one per instance in the order they
        were placed, and recommit: only the top level is rebuilt, the instanced meshes' BVHs stay as they
        are (Embree: rtcSetGeometryTransform and rtcCommitGeometry on each moved instance, then
        rtcCommitScene). The result is the scene a new Scene of these transforms would be. Call between
        queries, never during one (Embree's rule for any scene change). Returns how many instances moved."""
        transforms = _transforms(world_from_object)
        if transforms.shape != self._transforms.shape:
            raise ValueError(f"set_transforms: {len(transforms)} transforms for {self.instance_count} instances")
        moved = np.flatnonzero((transforms != self._transforms).any(axis=(1, 2)))
        if not len(moved):
            return 0
        lib = self.device.lib
        for k in moved:
            geom = lib.rtcGetGeometry(self.handle, 1 + int(k))   # borrowed: the scene holds the reference
            lib.rtcSetGeometryTransform(geom, 0, _FORMAT_FLOAT3X4_ROW_MAJOR, transforms[k].ctypes.data)
            lib.rtcCommitGeometry(geom)
        lib.rtcCommitScene(self.handle)
        self.device.check("the moved instances")
        self._transforms = transforms
        return len(moved)

    def embreex(self):
        """An embreex EmbreeScene tracing this scene (its run() loop, prim ids within their meshes, no
        instance ids), or None where embreex's layout is not the expected one."""
        slot = _embreex_slot()
        if slot is False:
            return None
        return _embreex_view(self.handle, self.device, slot)

    def _packets(self, origins, directions, t_max, rows: int, times=None):
        """Rays packed into (P, rows, 16) float32 packets, and the valid mask of the last packet. times: (N,) each
        ray's time in [0, 1] for geometries with time steps, or None (0)."""
        n = len(origins)
        p = -(-n // _LANES)
        buf = aligned_empty((p, rows, _LANES), np.float32)
        full = n // _LANES
        tail = n - full * _LANES
        columns = ((_ORG, origins[:, 0]), (_ORG + 1, origins[:, 1]), (_ORG + 2, origins[:, 2]),
                   (_DIR, directions[:, 0]), (_DIR + 1, directions[:, 1]), (_DIR + 2, directions[:, 2]),
                   (_TFAR, t_max))
        for row, values in columns:
            buf[:full, row, :] = values[:full * _LANES].reshape(full, _LANES)
            if tail:
                buf[full, row, :tail] = values[full * _LANES:]
                buf[full, row, tail:] = 0.0
        buf[:, _TNEAR, :] = 0.0
        buf[:, _TIME, :] = 0.0
        if times is not None:
            buf[:full, _TIME, :] = times[:full * _LANES].reshape(full, _LANES)
            if tail:
                buf[full, _TIME, :tail] = times[full * _LANES:]
        bits = buf.view(np.uint32)
        bits[:, _MASK, :] = INVALID
        bits[:, _ID, :] = 0
        bits[:, _FLAGS, :] = 0
        last = self._valid_all
        if tail:
            last = aligned_empty((_LANES,), np.int32)
            last[:] = 0
            last[:tail] = -1
        return buf, last

    def _trace(self, fn, buf: np.ndarray, last: np.ndarray) -> None:
        """One 16-ray query (rtcIntersect16 or rtcOccluded16) per packet of buf (P, rows, 16), every lane
        valid but in the last packet, whose mask is `last`. ctypes releases the GIL during each call."""
        scene, base, stride, p = self.handle, buf.ctypes.data, buf.shape[1] * _LANES * 4, len(buf)
        valid = self._valid_all.ctypes.data
        for i in range(p - 1):
            fn(valid, scene, base + i * stride, None)
        if p:
            fn(last.ctypes.data, scene, base + (p - 1) * stride, None)

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray, geometry: bool = False,
                  times: np.ndarray | None = None):
        """Closest hits of (N, 3) float32 rays within (N,) t_max: (prim, instance, t, u, v), with prim -1
        and t = t_max for a miss, instance -1 for hits on the plain mesh and the shapes; geometry: then also
        each hit's geometry (the top level's for hits outside instances, the instanced scene's within) and its
        (N, 3) unnormalised geometric normal, Embree's Ng. times: (N,) the rays' times (time steps), or None."""
        n = len(origins)
        buf, last = self._packets(origins, directions, t_max, _HIT_ROWS, times)
        bits = buf.view(np.uint32)
        bits[:, _PRIM:_INST + 1, :] = INVALID
        self._trace(self.device.lib.rtcIntersect16, buf, last)
        prim = bits[:, _PRIM, :].reshape(-1)[:n].view(np.int32)
        inst = bits[:, _INST, :].reshape(-1)[:n].view(np.int32)
        inst = np.where((inst < 0) | (prim < 0), np.int32(-1), inst - np.int32(1))
        out = (prim, inst, buf[:, _TFAR, :].reshape(-1)[:n], buf[:, _U, :].reshape(-1)[:n],
               buf[:, _V, :].reshape(-1)[:n])
        if geometry:
            ng = np.stack([buf[:, _NG + k, :].reshape(-1)[:n] for k in range(3)], axis=1)
            out += (bits[:, _GEOM, :].reshape(-1)[:n].view(np.int32), ng)
        return out

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray,
                 times: np.ndarray | None = None) -> np.ndarray:
        """(N,) bool: something lies on the ray before t_max (at the rays' times, or None)."""
        n = len(origins)
        buf, last = self._packets(origins, directions, t_max, _RAY_ROWS, times)
        self._trace(self.device.lib.rtcOccluded16, buf, last)
        # Embree marks an occluded ray by setting its tfar to -inf.
        return buf[:, _TFAR, :].reshape(-1)[:n] < 0


def quaternion_steps(decomposed) -> np.ndarray:
    """(S, 16) float32, 64-byte aligned: Embree's RTCQuaternionDecomposition of each motion step of a
    kernels.motion.Decomposed (world = T R S with S upper triangular), filled as Cycles' add_instance fills it
    (intern/cycles/bvh/embree.cpp): scale, skew (xy, xz, yz), shift 0, the quaternion (r, i, j, k) = (w, x, y, z),
    translation. Embree slerps the quaternion and lerps the rest between steps."""
    rotation, translation, scale = (np.asarray(a, np.float64) for a in decomposed)
    out = aligned_empty((len(rotation), 16), np.float32)
    out[:, 0], out[:, 1], out[:, 2] = scale[:, 0, 0], scale[:, 1, 1], scale[:, 2, 2]
    out[:, 3], out[:, 4], out[:, 5] = scale[:, 0, 1], scale[:, 0, 2], scale[:, 1, 2]
    out[:, 6:9] = 0.0
    out[:, 9], out[:, 10:13] = rotation[:, 3], rotation[:, :3]
    out[:, 13:16] = translation
    return out


def _transforms(world_from_object) -> np.ndarray:
    """(K, 3, 4) float32 row-major rows of (K, 3 or 4, 4) matrices: the layout Embree is handed."""
    m = np.asarray(world_from_object, np.float64)
    if not m.size:
        return np.zeros((0, 3, 4), np.float32)
    return np.ascontiguousarray(m[:, :3, :4], np.float32)


_EMBREEX_SLOT = None   # byte offset of EmbreeScene's scene handle, False when it could not be located


def _embreex_slot():
    """The byte offset of EmbreeScene.scene_i inside the Python object (Cython declares it just before
    the public int is_committed), or False."""
    global _EMBREEX_SLOT
    if _EMBREEX_SLOT is None:
        from embreex import rtcore_scene
        probe = rtcore_scene.EmbreeScene(robust=True)
        marker = 0x5EED7A1E
        probe.is_committed = marker
        words = (ctypes.c_int32 * 32).from_address(id(probe))
        hits = [i for i in range(32) if words[i] == marker]
        probe.is_committed = 0
        slot = hits[0] * 4 - 8 if len(hits) == 1 and hits[0] * 4 >= 24 and hits[0] % 2 == 0 else False
        _EMBREEX_SLOT = slot
        if slot is not False:
            _EMBREEX_SLOT = slot if _check_embreex_view() else False
    return _EMBREEX_SLOT


def _embreex_view(handle, device: Device, slot: int):
    from embreex import rtcore_scene
    view = rtcore_scene.EmbreeScene(robust=True)
    cell = ctypes.c_void_p.from_address(id(view) + slot)
    own = cell.value
    view.is_committed = 0
    device.lib.rtcRetainScene(handle)
    cell.value = handle
    if own:
        device.lib.rtcReleaseScene(own)   # embreex's own empty scene
    view.is_committed = 1
    return view


def _check_embreex_view() -> bool:
    device = Device()
    mesh = Triangles(np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32))
    scene = Scene(device, mesh)
    view = _embreex_view(scene.handle, device, _EMBREEX_SLOT)
    hit = view.run(np.array([[0.25, 0.25, 0.0]], np.float32), np.array([[0, 0, 1]], np.float32),
                   dists=np.array([10.0], np.float32), output=1)
    return int(hit["primID"][0]) == 0 and abs(float(hit["tfar"][0]) - 1.0) < 1e-6
