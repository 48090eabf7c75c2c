"""SceneArrays, the record of arrays the engine hands the kernel, with its validation (every part checked, bad
triangles dropped: ValidatedScene)."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .camera import Camera
from .checks import check_array, require, require_finite
from .curves import Curves
from .instances import Instances, ShapeInstances, clean_instances
from .light_groups import LightGroups
from .lights import Lights
from .links import LightLinks
from .materials import Materials
from .objects import OBJECT_COLUMNS, mirrored_objects, object_space_objects
from .points import Points
from .triangles import check_material_ids, check_triangles, clean_triangles, same_arrays, same_triangles
from .world import World


@dataclass(frozen=True)
class SceneArrays:
    """A whole scene as arrays. Build it, call validate(), hand it to kernels.render().

    positions : (T, 3, 3) float32, world-space corners of each triangle, or a CornerRows standing for them.
        A triangle's front (its geometric normal) is the side cross(p1 - p0, p2 - p0) points to, except on
        the triangles of a mirroring object row (mirrored_objects), which keep their mesh's winding and
        whose front is the other side, as in Blender; an instance with a mirroring transform likewise.
    normals : (T, 3, 3) float32, per-corner shading normals (need not be unit length), or a CornerRows
        standing for that array.
    uvs : (T, 3, 2) float32, per-corner texture coordinates.
    material_ids : (T,) int32, rows of `materials`.
    textures : tuple of (H, W, C) arrays, C in {1, 3, 4}, row 0 at the bottom: float32, or uint8 for 8-bit
        images (k stands for k / 255), uint16 for 16-bit ones (k / 65535); a 4-channel one holds its colour
        as it is to be filtered (associated with alpha where Cycles associates it: kernels.textures.Texture).
    texture_srgb : tuple of bool, one per texture (or empty: all linear). True marks a texture stored
        sRGB-encoded and decoded after filtering, as Cycles does with 8- and 16-bit sRGB images.
    tangents : (T, 3, 4) float32 or None: per-corner world-space MikkTSpace tangent (xyz) of the render
        UV map and its bitangent sign (w, +-1: B = sign * N x T); None when no material reads tangents
        (tangent-space normal maps, Tangent nodes). Zero rows mean "no tangent" (Cycles then leaves the
        normal unperturbed).
    attributes : ((name, (T, 3, C) float32), ...) per-corner attributes the node programs read, C in 1..4:
        "uv:<map>" (C = 2), "color:<name>" (vertex colours, C = 4), "attr:<name>" (generic attributes).
    objects : (K, OBJECT_COLUMNS) float32 or None: one row per object instance (OBJ_* columns), for
        the Texture Coordinate (Generated, Object, Normal) and Object Info nodes.
    object_attributes : ((name, (K, 4) float32), ...) per row of `objects`, the RGBA values of the Attribute
        node's Object ("object:<name>") and Instancer ("instancer:<name>") attributes; zero (alpha too) where
        an object has none, as in Cycles.
    object_ids : (T,) int32 or None: each triangle's row of `objects` (both or neither are given).
    object_visibility : (K,) uint8 or None, per row of `objects`: the rays that see the object (Cycles'
        PathRayVisibilityFlag bits, kernels.visibility: camera 1, transmission 2, diffuse 4, glossy 8,
        volume scatter 16, shadow 32), 64 for a shadow catcher and 128 for a holdout; None: every ray sees every
        object, none is a shadow catcher or a holdout.
    light_links : LightLinks or None, per row of `objects`: the light and shadow sets of Light and Shadow
        Linking; None: no object is linked and every emissive object lights everything (lights keep their own
        masks: Lights.light_sets, shadow_sets).
    light_groups : LightGroups or None: the light groups (View Layer > Light Groups) of the emissive objects,
        per row of `objects`, and of the world; None: none is in a group (lamps keep theirs in
        Lights.light_groups).
    motion : ((K, 4, 4) float64, ...) world_from_object at K >= 2 motion steps evenly spread over the
        shutter (time 0 to 1), one entry per moving object; motion_reference, one (4, 4) per entry: the
        matrix the triangles' world-space positions were made with. motion_ids : (T,) int32 or None:
        each triangle's entry of `motion`, -1 for static triangles.
    deform_ids : (T,) int32 or None: each triangle's column of deform_positions, -1 for triangles that do not
        deform (deformation motion blur); deform_positions, deform_normals : (S, D, 3, 3) float32, the deforming
        triangles' corners and corner normals at S >= 2 steps evenly spread over the shutter, in the space of
        `positions` (for a moving object the one its motion_reference made), interpolated linearly between
        the two nearest steps at a path's time (Cycles' motion triangles: kernel/geom/motion_triangle.h).
    shutter_table : (256,) float32 or None: path time from a uniform number (kernels.motion.shutter_table);
        rolling_shutter : None, or the rolling shutter's duration (Cycles' TOP rolling shutter).
    vector_motion : the Vector pass's neighbours in time, or None: ((K, 3, 4) per object row taking stored
        positions to the previous frame's, (K, 3, 4) to the next frame's, (4, 4) world_from_camera of the
        previous frame, (4, 4) of the next).
    vector_deform_ids : (T,) int32 or None: each triangle's column of vector_deform, -1 for triangles that do not
        deform between the frames; vector_deform : (2, D, 3, 3) float32, the deforming triangles' world-space
        corners at the previous and the next frame (the Vector pass reads them at a hit's barycentrics).
    crypto_ids : Cryptomatte ids (kernels.cryptomatte.hash_name of the names), or None: {"object": (K,) and
        "asset": (K,) float32 per row of `objects`, "material": (M,) float32 per material}.
    instances : Instances or None: meshes stored once in object space and placed by transforms, besides
        the T plain triangles above. They never move during the shutter (moving objects are plain).
    bvh_vertices, bvh_indices : (V, 3) float32 and (T, 3) uint32, or None: the plain triangles again as an
        indexed mesh, vertices[indices] equal to positions corner for corner (the export has them at hand);
        Embree builds its BVH from them about 1.5x faster than from the corners. Optional.
    volumes : ((object row, {name: kernels.media.grid.VoxelGrid}, density scale, step), ...): the voxel grids of
        the objects that are volumes (Volume objects, smoke domains), looked up by their media's shaders, the
        factor on their coefficients (Cycles' object_volume_density), and the world-space step the Biased
        option marches them with before the Step Rates (0: none).
    curves : (kernels.scene.Curves, ...) in world space, one record per shape (Cycles' curve shape of the scene,
        and linear for curves of poly type); their object_ids are rows of `objects`.
    points : kernels.scene.Points in world space, or None.
    shape_instances : kernels.scene.ShapeInstances (curves and points stored once in object space, placed by
        transforms), or None. A scene without any of these three renders triangles only, at no cost of theirs.
    """
    positions: np.ndarray
    normals: np.ndarray
    uvs: np.ndarray
    material_ids: np.ndarray
    materials: Materials = field(default_factory=Materials)
    textures: tuple = ()
    texture_srgb: tuple = ()
    world: World = field(default_factory=World)
    camera: Camera = field(default_factory=Camera)
    lights: Lights = field(default_factory=Lights)
    tangents: np.ndarray | None = None
    attributes: tuple = ()
    objects: np.ndarray | None = None
    object_ids: np.ndarray | None = None
    motion: tuple = ()
    motion_reference: tuple = ()
    motion_ids: np.ndarray | None = None
    deform_ids: np.ndarray | None = None
    deform_positions: np.ndarray | None = None
    deform_normals: np.ndarray | None = None
    shutter_table: np.ndarray | None = None
    rolling_shutter: float | None = None
    crypto_ids: dict | None = None
    vector_motion: tuple | None = None
    vector_deform_ids: np.ndarray | None = None
    vector_deform: np.ndarray | None = None
    instances: Instances | None = None
    bvh_vertices: np.ndarray | None = None
    bvh_indices: np.ndarray | None = None
    volumes: tuple = ()
    object_attributes: tuple = ()
    object_visibility: np.ndarray | None = None
    light_links: LightLinks | None = None
    light_groups: LightGroups | None = None
    curves: tuple = ()
    points: Points | None = None
    shape_instances: ShapeInstances | None = None

    @property
    def has_shapes(self) -> bool:
        """The scene has curves or points (kernels.geometry.primitives then joins them to the triangles)."""
        return bool(self.curves) or self.points is not None or self.shape_instances is not None

    @property
    def has_motion(self) -> bool:
        """Anything moves during the shutter: paths then carry a time."""
        return self.shutter_table is not None and (self.camera.motion is not None or len(self.motion) > 0
                                                   or self.deform_ids is not None
                                                   or self.camera.fov_motion is not None or self.shapes_move)

    @property
    def shapes_move(self) -> bool:
        """Some curves or points have motion keys (their records' motion) or are placed by moving instances."""
        records = list(self.curves) + ([self.points] if self.points is not None else [])
        placed = self.shape_instances
        if placed is not None:
            records += list(placed.prototypes)
        return any(getattr(r, "motion", None) is not None for r in records) or (placed is not None and placed.moves)

    @property
    def triangle_count(self) -> int:
        """Plain triangles (instanced ones not counted: see instanced_triangle_count)."""
        return len(self.positions)

    @property
    def instanced_triangle_count(self) -> int:
        return 0 if self.instances is None else self.instances.triangle_total

    def mirrored_triangles(self) -> np.ndarray | None:
        """(T,) bool: the plain triangles whose object mirrors them (mirrored_objects), whose front is the
        side opposite the winding's; None when none is (or the scene has no object table)."""
        if self.objects is None or self.object_ids is None or not len(self.objects):
            return None
        mirrored = mirrored_objects(self.objects)
        return np.take(mirrored, self.object_ids) if mirrored.any() else None

    def object_space_triangles(self) -> np.ndarray | None:
        """(T,) bool: the plain triangles whose object interpolates its normals in object space
        (object_space_objects); None when none does."""
        if self.object_ids is None:
            return None
        flags = object_space_objects(self.objects)
        return None if flags is None else np.take(flags, self.object_ids)

    def validate(self, clean: "SceneArrays | None" = None) -> "ValidatedScene":
        """Check every field; drop degenerate or non-finite triangles.

        Raises ValueError naming the field for wrong shapes, dtypes, indices or non-finite data
        in anything but triangle corners. Returns the cleaned scene and the number of dropped triangles.
        clean : a scene validate() returned before (the last frame's): triangles equal to its own, plain or
        of a prototype, are known clean and not looked at again.
        """
        t = len(self.positions) if hasattr(self.positions, "__len__") else -1
        check_triangles(self, "", None)
        self.validate_objects()
        require(len(self.motion) == len(self.motion_reference), "motion_reference", "needs one matrix per motion")
        for i, keys in enumerate(self.motion):
            keys = np.asarray(keys)
            require(keys.ndim == 3 and keys.shape[0] >= 2 and keys.shape[1:] == (4, 4), f"motion[{i}]",
                    f"must be (K >= 2, 4, 4), got {keys.shape}")
            require_finite(keys, f"motion[{i}]")
        if self.motion_ids is not None:
            check_array(self.motion_ids, "motion_ids", (t,), np.int32)
            if t:
                require(self.motion_ids.min() >= -1 and self.motion_ids.max() < len(self.motion), "motion_ids",
                        f"must be in [-1, {len(self.motion)})")
        if self.deform_ids is not None:
            check_array(self.deform_ids, "deform_ids", (t,), np.int32)
            steps = np.asarray(self.deform_positions)
            require(steps.ndim == 4 and steps.shape[0] >= 2 and steps.shape[2:] == (3, 3), "deform_positions",
                    f"must be (S >= 2, D, 3, 3), got {steps.shape}")
            check_array(self.deform_positions, "deform_positions", steps.shape, np.float32)
            check_array(self.deform_normals, "deform_normals", steps.shape, np.float32, finite=False)
            if t:
                require(self.deform_ids.min() >= -1 and self.deform_ids.max() < steps.shape[1], "deform_ids",
                        f"must be in [-1, {steps.shape[1]})")
        require((self.vector_deform_ids is None) == (self.vector_deform is None), "vector_deform",
                "vector_deform_ids and vector_deform come together")
        if self.vector_deform_ids is not None:
            check_array(self.vector_deform_ids, "vector_deform_ids", (t,), np.int32)
            corners = np.asarray(self.vector_deform)
            require(corners.ndim == 4 and corners.shape[0] == 2 and corners.shape[2:] == (3, 3), "vector_deform",
                    f"must be (2, D, 3, 3), got {corners.shape}")
            check_array(self.vector_deform, "vector_deform", corners.shape, np.float32)
            if t:
                require(self.vector_deform_ids.min() >= -1 and self.vector_deform_ids.max() < corners.shape[1],
                        "vector_deform_ids", f"must be in [-1, {corners.shape[1]})")
        if self.shutter_table is not None:
            check_array(self.shutter_table, "shutter_table", (len(self.shutter_table),), np.float32)
        self.validate_shading()
        if self.instances is not None:
            self.instances.validate(self.materials.count, None if self.objects is None else len(self.objects))
        self.camera.validate()
        self.lights.validate()

        require((self.bvh_vertices is None) == (self.bvh_indices is None), "bvh_vertices",
                "bvh_vertices and bvh_indices come together")
        if self.bvh_vertices is not None:
            check_array(self.bvh_vertices, "bvh_vertices", (len(self.bvh_vertices), 3), np.float32, finite=False)
            check_array(self.bvh_indices, "bvh_indices", (t, 3), np.uint32)
            if t:
                require(int(self.bvh_indices.max()) < len(self.bvh_vertices), "bvh_indices",
                        f"must be below {len(self.bvh_vertices)}")
        if clean is not None and same_triangles(self, clean) and same_arrays(self.bvh_indices, clean.bvh_indices):
            changes, dropped, repaired, nonfinite = {}, 0, 0, 0
        else:
            changes, dropped, repaired, nonfinite = clean_triangles(self, ("object_ids", "motion_ids", "deform_ids", "vector_deform_ids",
                                                                        "bvh_indices"))
        if self.instances is not None:
            changes["instances"], more_dropped, more_repaired, more_nonfinite = clean_instances(
                self.instances, clean.instances if clean is not None else None)
            dropped += more_dropped
            nonfinite += more_nonfinite
            repaired += more_repaired
        shapes_dropped = 0
        if self.has_shapes:
            changes.update(self._cleaned_shapes())
            shapes_dropped = changes.pop("shapes_dropped")
        scene = dataclasses.replace(self, **changes) if changes else self
        return ValidatedScene(scene, dropped, repaired, nonfinite, shapes_dropped)

    def _cleaned_shapes(self) -> dict:
        """Curves and points checked and cleaned (the ones Embree cannot take dropped, counted in
        shapes_dropped)."""
        objects = None if self.objects is None else len(self.objects)
        count = self.materials.count
        curves, dropped = [], 0
        for i, record in enumerate(self.curves):
            require(isinstance(record, Curves), f"curves[{i}]", "must be a kernels.scene.Curves")
            record.validate(f"curves[{i}]", count, objects)
            require(record.object_ids is not None or self.objects is None, f"curves[{i}].object_ids",
                    "given when the scene has objects")
            kept, d = record.cleaned()
            curves.append(kept)
            dropped += d
        points = self.points
        if points is not None:
            require(isinstance(points, Points), "points", "must be a kernels.scene.Points")
            points.validate("points", count, objects)
            require(points.object_ids is not None or self.objects is None, "points.object_ids",
                    "given when the scene has objects")
            points, d = points.cleaned()
            dropped += d
        placed = self.shape_instances
        if placed is not None:
            placed.validate(count, objects)
            placed, d = placed.cleaned()
            dropped += d
        return {"curves": tuple(curves), "points": points, "shape_instances": placed, "shapes_dropped": dropped}

    def validate_objects(self) -> None:
        """Check the object table and each triangle's row of it (part of validate(); on its own when the
        viewport moves objects: Renderer.update_instances)."""
        t = len(self.positions) if hasattr(self.positions, "__len__") else -1
        require((self.objects is None) == (self.object_ids is None), "objects",
                "objects and object_ids come together")
        if self.objects is not None:
            k = len(self.objects)
            check_array(self.objects, "objects", (k, OBJECT_COLUMNS), np.float32)
            check_array(self.object_ids, "object_ids", (t,), np.int32)
            if t:
                require(self.object_ids.min() >= 0 and self.object_ids.max() < k, "object_ids",
                        f"must be in [0, {k})")
        if self.object_visibility is not None:
            require(self.objects is not None, "object_visibility", "needs the object table")
            check_array(self.object_visibility, "object_visibility", (len(self.objects),), np.uint8)
        if self.light_links is not None:
            require(self.objects is not None, "light_links", "needs the object table")
            self.light_links.validate(len(self.objects))
        if self.light_groups is not None:
            self.light_groups.validate(0 if self.objects is None else len(self.objects))
        for name, values in self.object_attributes:
            k = 0 if self.objects is None else len(self.objects)
            check_array(values, f"object_attributes[{name!r}]", (k, 4), np.float32)

    def validate_shading(self) -> None:
        """Check textures, materials and the world against each other and the triangles' material ids (part
        of validate(); on its own when the viewport edits materials: Renderer.update_materials)."""
        for i, tex in enumerate(self.textures):
            require(isinstance(tex, np.ndarray) and tex.ndim == 3 and tex.shape[2] in (1, 3, 4)
                    and tex.shape[0] >= 1 and tex.shape[1] >= 1,
                    f"textures[{i}]", f"must be an (H, W, C) array with C in 1, 3, 4, got "
                    f"{getattr(tex, 'shape', type(tex).__name__)}")
            integer = tex.dtype in (np.uint8, np.uint16)
            check_array(tex, f"textures[{i}]", tex.shape, tex.dtype if integer else np.float32, finite=not integer)
        require(len(self.texture_srgb) in (0, len(self.textures)), "texture_srgb",
                f"needs one flag per texture ({len(self.textures)}), got {len(self.texture_srgb)}")
        self.materials.validate(len(self.textures))
        if self.world.program is not None:
            self.world.program.validate(len(self.textures))
        check_material_ids(self, "", self.materials.count)
        if self.instances is not None:
            for i, proto in enumerate(self.instances.prototypes):
                check_material_ids(proto, f"instances.prototypes[{i}].", self.materials.count)
        self.world.validate()


@dataclass(frozen=True)
class ValidatedScene:
    """A SceneArrays that passed validate(), with what cleaning it took."""
    scene: SceneArrays
    dropped_triangles: int
    repaired_normals: int
    nonfinite_triangles: int = 0    # of the dropped: corners not finite (NaN, or beyond float32)
    dropped_shapes: int = 0         # curves and points dropped (a key, centre or radius not finite, a negative radius)
