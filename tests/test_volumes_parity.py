"""Volumes against Cycles (CPU, no clamping, box filter), as test_parity_materials compares: four seed
replicates per engine; the whole-image mean within 2% and every block of an 8x8 grid within 4.5 standard errors
of the difference. Each scene is one a user makes: a Principled Volume cloud with an invisible boundary,
glass filled with a coloured absorption, world fog crossed by a spot light's beam, a camera inside a fog box,
a Noise texture driving density, each Volume Scatter phase function, emission and blackbody, Volume
Coefficients, overlapping media, multiple scattering, and a Volume object reading an OpenVDB file."""

import bpy
import numpy as np
import pytest

from bpy_helpers import REPLICATE_SEEDS, add_camera, compare_to_cycles, mesh_object, new_scene, set_world
from test_volumes import box, set_volume_bounces, volume_material

FLOOR = [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)]


def stage(width=48, height=48, world=(0.4, 0.5, 0.7)):
    """A floor, a camera looking at the origin from the front, a world colour."""
    scene = new_scene(width, height)
    mesh_object("Floor", FLOOR, [(0, 1, 2, 3)])
    add_camera(scene, (0, -4, 1.6), (0, 0, 0.6), lens=40)
    set_world(scene, color=world)
    return scene


def lamp(scene, kind, location, energy, size=0.2, rotation=(0.0, 0.0, 0.0), spot_size=None):
    data = bpy.data.lights.new(kind, kind)
    data.energy = energy
    if kind != "SUN":
        data.shadow_soft_size = size
    if spot_size is not None:
        data.spot_size = spot_size
    ob = bpy.data.objects.new(kind, data)
    scene.collection.objects.link(ob)
    ob.location, ob.rotation_euler = location, rotation
    return ob


def compare(scene, samples=128, volume_bounces=0, **kwargs):
    set_volume_bounces(scene, volume_bounces)
    return compare_to_cycles(scene, samples=samples, max_bounces=6, **kwargs)


def test_principled_volume_cloud_with_an_invisible_boundary():
    """The issue's first case: a cube whose material has only a Principled Volume (orange, density 3) is an
    orange cloud behind an invisible boundary, lit by a lamp and the world."""
    scene = stage()
    m, _ = volume_material("Cloud", "ShaderNodeVolumePrincipled", Color=(0.9, 0.5, 0.2, 1.0), Density=3.0,
                           Anisotropy=0.3)
    box("Cloud", (-0.6, -0.6, 0.1), (0.6, 0.6, 1.3), m)
    lamp(scene, "POINT", (2, -2, 3), 400)
    compare(scene)


def test_glass_filled_with_coloured_absorption():
    """Clear glass around a red Volume Absorption: red glass, its light through it red too (the floor's
    caustic is the glass's, the same in both)."""
    scene = stage()
    m, _ = volume_material("Red glass", "ShaderNodeVolumeAbsorption", "ShaderNodeBsdfGlass",
                           Color=(0.9, 0.3, 0.3, 1.0), Density=2.0)
    box("Glass", (-0.5, -0.5, 0.1), (0.5, 0.5, 1.1), m)
    lamp(scene, "SUN", (0, 0, 5), 3.0, rotation=(0.4, 0.2, 0.0))
    compare(scene, samples=256)


def test_world_fog_and_a_spot_lights_beam():
    """A Volume Scatter world (fog everywhere) crossed by a spot light's beam: the beam, the fog's glow and the
    fog's veil over the floor and a box."""
    scene = stage(world=(0.02, 0.02, 0.03))
    tree = scene.world.node_tree
    fog = tree.nodes.new("ShaderNodeVolumeScatter")
    fog.inputs["Density"].default_value = 0.08
    tree.links.new(fog.outputs[0], next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld")
                   .inputs["Volume"])
    box("Box", (-0.3, -0.3, 0.0), (0.3, 0.3, 0.6))
    lamp(scene, "SPOT", (1.5, -1.0, 3.0), 800, rotation=(0.4, 0.3, 0.0), spot_size=0.6)
    compare(scene, samples=256)


def test_camera_inside_a_fog_box_with_a_point_light():
    """The camera inside a big box of scattering medium (its stack starts with the box's medium), anisotropic
    forward scattering, a lamp inside too."""
    scene = stage()
    m, _ = volume_material("Fog", "ShaderNodeVolumeScatter", Density=0.15, Anisotropy=0.4)
    box("Fog box", (-5, -6, -1), (5, 5, 5), m)
    box("Box", (-0.3, -0.3, 0.0), (0.3, 0.3, 0.6))
    lamp(scene, "POINT", (1.0, -1.0, 2.5), 300)
    compare(scene)


def test_density_from_a_noise_texture():
    """A heterogeneous medium: Principled Volume density = 6 x a Noise texture (null scattering against an
    estimated majorant), lit by a lamp. Two replicates of 64 spp each: each Cycles render of it takes 3 s to start
    (its majorant grid), most of the test's time."""
    scene = stage(32, 32)
    m, node = volume_material("Smoke", "ShaderNodeVolumePrincipled", Color=(0.8, 0.8, 0.8, 1.0))
    tree = m.node_tree
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 3.0
    scale = tree.nodes.new("ShaderNodeMath")
    scale.operation, scale.inputs[1].default_value = "MULTIPLY", 6.0
    tree.links.new(noise.outputs["Fac"], scale.inputs[0])
    tree.links.new(scale.outputs[0], node.inputs["Density"])
    box("Smoke", (-0.6, -0.6, 0.1), (0.6, 0.6, 1.3), m)
    lamp(scene, "POINT", (2, -2, 3), 400)
    compare(scene, seeds=REPLICATE_SEEDS[:2])


def test_each_phase_function_of_volume_scatter():
    """Four cubes scattering with Fournier-Forand, Draine, Rayleigh and Mie (its default 20 um droplets), one
    bounce of multiple scattering."""
    scene = stage(64, 32)
    scene.camera.data.lens = 30
    for i, phase in enumerate(("FOURNIER_FORAND", "DRAINE", "RAYLEIGH", "MIE")):
        m, _ = volume_material(phase, "ShaderNodeVolumeScatter", Color=(0.8, 0.7, 0.6, 1.0), Density=2.5,
                               Anisotropy=0.4, phase=phase)
        box(phase, (-2.0 + i, -0.35, 0.1), (-1.3 + i, 0.35, 0.8), m)
    lamp(scene, "POINT", (1.5, -2.0, 3.0), 500)
    compare(scene, samples=256, volume_bounces=1)


def test_volume_emission_blackbody_and_an_emission_shader():
    """A Principled Volume glowing with Emission Strength and blackbody at 1500 K, and an Emission shader in a
    Volume output (light per unit length), in the dark."""
    scene = stage(world=(0.01, 0.01, 0.01))
    m, _ = volume_material("Fire", "ShaderNodeVolumePrincipled", Density=1.0, **{
        "Emission Strength": 2.0, "Emission Color": (1.0, 0.5, 0.2, 1.0), "Blackbody Intensity": 0.5,
        "Temperature": 1500.0})
    box("Fire", (-1.1, -0.4, 0.1), (-0.1, 0.4, 1.1), m)
    glow, _ = volume_material("Glow", "ShaderNodeEmission", Color=(0.2, 0.6, 1.0, 1.0), Strength=1.5)
    box("Glow", (0.1, -0.4, 0.1), (1.1, 0.4, 1.1), glow)
    compare(scene)


def test_volume_coefficients_and_overlapping_media():
    """Volume Coefficients (absorption, scattering and emission per channel) in a box that overlaps a Volume
    Absorption box: where they overlap, both at once (the stack holds both)."""
    scene = stage()
    m, node = volume_material("Coefficients", "ShaderNodeVolumeCoefficients", **{
        "Absorption Coefficients": (0.5, 1.0, 2.0), "Scatter Coefficients": (2.0, 1.5, 1.0),
        "Emission Coefficients": (0.1, 0.05, 0.0)})
    box("A", (-0.9, -0.5, 0.1), (0.3, 0.5, 1.1), m)
    blue, _ = volume_material("Blue", "ShaderNodeVolumeAbsorption", Color=(0.2, 0.4, 0.9, 1.0), Density=1.5)
    box("B", (-0.2, -0.3, 0.3), (0.9, 0.3, 1.4), blue)
    lamp(scene, "POINT", (2, -2, 3), 400)
    compare(scene)


def test_multiple_scattering_in_a_dense_cloud():
    """A dense white cloud (optical radius about 5) with 8 volume bounces: most of its light is scattered
    several times."""
    scene = stage()
    m, _ = volume_material("Dense", "ShaderNodeVolumePrincipled", Color=(0.95, 0.95, 0.95, 1.0), Density=8.0)
    box("Dense", (-0.6, -0.6, 0.1), (0.6, 0.6, 1.3), m)
    lamp(scene, "SUN", (0, 0, 5), 3.0, rotation=(0.5, 0.3, 0.0))
    compare(scene, samples=128, volume_bounces=8)


def vdb_ball(tmp_path, scale):
    """A Volume object at (0, 0, 0.8) reading a .vdb written here with Blender's own openvdb module: a noisy
    ball of density (scale x (1 - r^2 / 10^2) x (1 + 0.5 sin 0.7 i), voxels 0.06 wide). Returns (volume, object);
    skips the test without the module."""
    from ember.engine.export.volumes import openvdb_module
    vdb = openvdb_module()
    if vdb is None:
        pytest.skip("Blender's openvdb module is not found")
    radius, n = 10, 11
    ijk = np.stack(np.meshgrid(*(np.arange(2 * n + 1) - n,) * 3, indexing="ij"), -1).astype(np.float64)
    density = scale * np.maximum(0.0, 1.0 - (ijk ** 2).sum(-1) / radius ** 2) * (1 + 0.5 * np.sin(0.7 * ijk[..., 0]))
    grid = vdb.FloatGrid()
    grid.name = "density"
    grid.copyFromArray(density.astype(np.float32), ijk=(-n, -n, -n))
    grid.transform = vdb.createLinearTransform(voxelSize=0.06)
    path = tmp_path / "ball.vdb"
    vdb.write(str(path), grids=[grid])
    volume = bpy.data.volumes.new("Ball")
    volume.filepath = str(path)
    ob = bpy.data.objects.new("Ball", volume)
    bpy.context.scene.collection.objects.link(ob)
    ob.location = (0.0, 0.0, 0.8)
    return volume, ob


def test_volume_object_from_an_openvdb_file(tmp_path):
    """Volume objects reading a .vdb file (a noisy ball of density, written here with Blender's own openvdb
    module): side by side in one scene, one with its default volume (no material), one with a Principled Volume
    of density 8. Two replicates of 64 spp each: each Cycles render of it takes seconds to start, most of the test's
    time, and with both balls little more than with the dense one alone."""
    scene = stage(32, 32)
    _, plain = vdb_ball(tmp_path, 1.0)
    volume, dense = vdb_ball(tmp_path, 1.0)
    plain.location.x, dense.location.x = -0.7, 0.7
    m, _ = volume_material("Ball", "ShaderNodeVolumePrincipled", Color=(0.9, 0.8, 0.7, 1.0), Density=8.0)
    volume.materials.append(m)
    lamp(scene, "POINT", (2, -2, 3), 400)
    compare(scene, seeds=REPLICATE_SEEDS[:2])


def _volume_passes(scene, engine, seed, samples):
    from bpy_helpers import configure_engine
    from exr import render_multilayer
    configure_engine(scene, engine, samples, seed, max_bounces=6)
    layer = scene.view_layers[0]
    layer.ember.use_pass_volume_direct = layer.ember.use_pass_volume_indirect = True
    if engine == "CYCLES":
        layer.cycles.use_pass_volume_direct = layer.cycles.use_pass_volume_indirect = True
    parts, _ = render_multilayer(scene)
    out = {}
    for name in ("Combined", "Volume Direct", "Volume Indirect"):
        planes = parts[f"{layer.name}.{name}"]
        out[name] = np.stack([planes[c] for c in "RGB"], axis=-1).astype(np.float64)
    return out


def test_volume_direct_and_indirect_passes():
    """Volume Direct and Indirect (light of paths whose first scattering is in a medium, direct when it lit that
    scattering point) against Cycles' passes, 4x4 blocks within 5 standard errors of two replicates each (plus 2%
    of the block, as test_passes_parity allows for what noise does not explain: two replicates estimate the
    spread loosely); and
    in Ember, Combined is the sum of the volume passes and the rest (a scene where only the medium and the
    world are seen: no surface in view)."""
    scene = new_scene(32, 32)
    set_world(scene, color=(0.1, 0.12, 0.15))
    m, _ = volume_material("Cloud", "ShaderNodeVolumePrincipled", Color=(0.9, 0.7, 0.5, 1.0), Density=2.0)
    box("Cloud", (-1.5, -1.5, 0.0), (1.5, 1.5, 2.0), m)
    lamp(scene, "POINT", (2.5, -2.5, 3.0), 600)
    set_volume_bounces(scene, 4)
    runs = {engine: [_volume_passes(scene, engine, seed, 64) for seed in (0, 1)] for engine in ("CYCLES", "EMBER")}
    for name in ("Volume Direct", "Volume Indirect"):
        def blocks(image):
            return image.reshape(4, 8, 4, 8, 3).mean(axis=(1, 3))
        means = {e: np.mean([blocks(r[name]) for r in runs[e]], axis=0) for e in runs}
        spread = sum(np.var([blocks(r[name]) for r in runs[e]], axis=0, ddof=1) / 2 for e in runs)
        se = np.sqrt(spread) + 0.02 * np.abs(means["CYCLES"]) + 1e-4
        z = np.abs(means["EMBER"] - means["CYCLES"]) / se
        assert z.max() < 5, (name, z.max(), means["EMBER"].mean(), means["CYCLES"].mean())
        assert means["CYCLES"].mean() > 1e-3
    for run in runs["EMBER"]:
        # The camera sees the cloud and the world behind it: Combined = Volume Direct + Indirect + what is seen
        # through the cloud of the world (its transmittance times the world, where no path scattered).
        rest = run["Combined"] - run["Volume Direct"] - run["Volume Indirect"]
        assert rest.min() > -1e-4 and (rest <= np.array([0.1, 0.12, 0.15]) + 1e-4).all()


def test_light_path_is_volume_scatter_ray():
    """A floor that is red to rays that scattered in a medium last (Light Path > Is Volume Scatter Ray drives a
    Mix Shader of two diffuse BSDFs) and grey to the rest, under a fog box: what the fog sees of the floor is
    red."""
    scene = stage()
    floor = bpy.data.materials.new("Floor")
    tree = floor.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    path = tree.nodes.new("ShaderNodeLightPath")
    grey = tree.nodes.new("ShaderNodeBsdfDiffuse")
    red = tree.nodes.new("ShaderNodeBsdfDiffuse")
    red.inputs["Color"].default_value = (0.9, 0.05, 0.05, 1.0)
    tree.links.new(path.outputs["Is Volume Scatter Ray"], mix.inputs[0])
    tree.links.new(grey.outputs[0], mix.inputs[1])
    tree.links.new(red.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    bpy.data.objects["Floor"].data.materials.append(floor)
    m, _ = volume_material("Fog", "ShaderNodeVolumeScatter", Density=1.5)
    box("Fog", (-0.7, -0.7, 0.3), (0.7, 0.7, 1.3), m)
    lamp(scene, "POINT", (2, -2, 3), 300)
    compare(scene, volume_bounces=1)


def set_biased(scene, biased=True, step_rate=1.0, max_steps=1024):
    """Render > Volumes > Biased on both engines, with its Step Rate and Max Steps."""
    for settings in (scene.ember, scene.cycles):
        settings.volume_biased = biased
        settings.volume_step_rate = step_rate
        settings.volume_max_steps = max_steps


def test_biased_ray_marching_of_a_noise_medium():
    """Render > Volumes > Biased with Step Rate 4 (steps of 0.48 across a 1.2 cube): a medium of density 15 where a
    Noise texture exceeds 0.5, else 0, marched with its coefficients constant over each step. Cycles' marched
    image is 3-4% brighter than the unbiased one (each step sees the medium at one point); Ember's matches
    Cycles' marched image, and its unbiased image stays more than 2% below it, by more than 4 standard errors of
    its mean."""
    from bpy_helpers import replicate_render
    scene = stage()
    m, node = volume_material("Chunks", "ShaderNodeVolumePrincipled", Color=(0.8, 0.8, 0.8, 1.0))
    tree = m.node_tree
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 3.0
    step = tree.nodes.new("ShaderNodeMath")
    step.operation, step.inputs[1].default_value = "GREATER_THAN", 0.5
    scale = tree.nodes.new("ShaderNodeMath")
    scale.operation, scale.inputs[1].default_value = "MULTIPLY", 15.0
    tree.links.new(noise.outputs["Fac"], step.inputs[0])
    tree.links.new(step.outputs[0], scale.inputs[0])
    tree.links.new(scale.outputs[0], node.inputs["Density"])
    box("Chunks", (-0.6, -0.6, 0.1), (0.6, 0.6, 1.3), m)
    lamp(scene, "POINT", (2, -2, 3), 400)
    set_biased(scene, step_rate=4.0)
    report = compare(scene)
    set_biased(scene, False)
    # Two replicates of 16 spp: the mean's standard error is a few hundredths of a percent, where the gap to
    # Cycles' marched image is 3-4%.
    unbiased, var = replicate_render(scene, "EMBER", 32, max_bounces=6, seeds=REPLICATE_SEEDS[:2])
    se = np.sqrt(var.sum()) / var.size
    assert unbiased.mean() + 4.0 * se < report["mean_cycles"] * 0.98, (unbiased.mean(), se, report)


def test_biased_ray_marching_of_a_vdb_with_few_steps(tmp_path):
    """A Volume object (a rotated OpenVDB ball of density, its voxels 0.06 wide) marched with Max Steps 4 (each
    segment in four steps, the last cut short by the first's random offset) and Step Rate 3, against Cycles'
    marched image; the step is the voxel size in world space, as Cycles takes it."""
    scene = stage()
    _, ob = vdb_ball(tmp_path, 8.0)
    ob.rotation_euler = (0.3, 0.2, 0.5)
    lamp(scene, "POINT", (2, -2, 3), 400)
    set_biased(scene, step_rate=3.0, max_steps=4)
    compare(scene)


def test_a_fog_box_cut_by_the_far_clip_plane_as_in_cycles():
    """A camera outside a fog box whose far clip plane cuts through it: a ray that ends at the clip plane meets no
    surface, and Cycles keeps only the world's medium for such a ray (volume_stack_clean in shade_volume.h): the
    box's fog shows only along the rays that leave it through a face before the clip plane. Before, Ember
    integrated the box's fog past the clip plane, without end: a public file's fog, cut by its camera's 100 m
    clip, rendered 3x brighter than in Cycles."""
    scene = stage(world=(0.0, 0.0, 0.0))
    m, _ = volume_material("Fog", "ShaderNodeVolumeScatter", Density=0.3)
    box("Fog box", (-1.5, -1.0, 0.2), (1.5, 3.0, 2.5), m)   # above the floor
    lamp(scene, "POINT", (0.0, 1.0, 1.2), 400)
    scene.camera.data.clip_end = 5.5   # the box's far face is 7 m away: the middle rays end inside it
    compare(scene)


def test_a_fog_box_standing_on_the_floor_lights_the_floor_as_fog_does():
    """A fog box whose bottom face lies in the floor's plane (three spheres in it under an area light): a camera ray
    that leaves the box through that face is handed the floor lying there and reflects back into the fog, so the
    floor is shaded and lit from inside the fog. Before, the ray left the fog first and the floor under the box
    took its light unattenuated: 1.1% brighter over the image (12 standard errors) than the same box lifted by
    0.1 mm, which both engines render alike. Cycles' own image of the box exactly on the floor is 4% darker than
    lifted (rays slipping between the coincident faces), so the reference is Cycles' image of the lifted box."""
    from bpy_helpers import node_material, replicate_render
    from test_light_linking import _spheres, within_noise
    scene, _, _ = _spheres()
    bpy.ops.mesh.primitive_cube_add(size=2.6, location=(0, 0, 1.3001))
    fog = bpy.context.object
    fog.data.materials.append(node_material("Fog", "ShaderNodeVolumePrincipled", output="Volume", Density=0.3))
    cycles, var_c = replicate_render(scene, "CYCLES", 64)
    fog.location.z = 1.3    # its bottom face in the floor's plane
    within_noise(*replicate_render(scene, "EMBER", 64), cycles, var_c)
