"""Materials against Cycles (CPU, no clamping, box filter): Cycles' closures, layers and mixes.

Same method as test_parity_cycles: four seed replicates per engine; the whole-image mean within 2% and
every block of an 8x8 grid within 4.5 standard errors of the difference.
"""
import bpy
import numpy as np
import pytest

from bpy_helpers import REPLICATE_SEEDS, add_camera, compare_to_cycles, diffuse_material, hdri_world, mesh_object, \
    new_scene, node_material, quad_object, render_to_array, replicate_render, set_world


def sphere(location, material, radius=0.45):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location, segments=32, ring_count=16)
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(material)


def grid_of_spheres(materials, columns):
    """Spheres one unit apart on a grid in the x-z plane, facing a camera on -y; a grey floor below."""
    rows = -(-len(materials) // columns)
    for i, mat in enumerate(materials):
        r, c = divmod(i, columns)
        sphere((c - (columns - 1) / 2, 0, (rows - 1 - r) + 0.5), mat)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.4, 0.4, 0.4)))
    return rows


@pytest.mark.xfail(bpy.app.version[:2] >= (5, 3), strict=True,
                   reason="Cycles 5.3's Oren-Nayar renders brighter than 5.0's from the same bsdf_oren_nayar.h "
                          "(docs/blender-versions.md): the Rough Diffuse sphere differs")
def test_principled_sphere_row_under_an_hdri():
    """Metal smooth and rough, plastic, glass, coat and sheen: the Principled layer stack."""
    scene = new_scene(96, 48)
    P = "ShaderNodeBsdfPrincipled"
    materials = [
        node_material("Chrome", P, Base_Color=(0.9, 0.8, 0.6), Metallic=1.0, Roughness=0.0),
        node_material("Brushed", P, Base_Color=(0.8, 0.5, 0.3), Metallic=1.0, Roughness=0.35,
                      Specular_Tint=(0.6, 0.8, 1.0)),
        node_material("Plastic", P, Base_Color=(0.7, 0.1, 0.1), Roughness=0.3),
        node_material("Glass", P, Base_Color=(0.9, 1.0, 0.9), Transmission_Weight=1.0, Roughness=0.0),
        node_material("Frosted", P, Transmission_Weight=1.0, Roughness=0.3, IOR=1.45),
        node_material("Coated", P, Base_Color=(0.1, 0.2, 0.7), Roughness=0.6, Coat_Weight=1.0,
                      Coat_Roughness=0.05, Coat_Tint=(0.9, 0.8, 0.6)),
        node_material("Velvet", P, Base_Color=(0.3, 0.05, 0.1), Sheen_Weight=1.0, Sheen_Roughness=0.4,
                      Sheen_Tint=(1.0, 0.9, 0.9)),
        node_material("Rough Diffuse", P, Base_Color=(0.6, 0.6, 0.5), Diffuse_Roughness=1.0,
                      Specular_IOR_Level=0.8, Roughness=0.7),
    ]
    grid_of_spheres(materials, 4)
    add_camera(scene, (0, -5.2, 1.0), (0, 0, 1.0), lens=45)
    hdri_world(scene, "forest.exr", strength=1.0, rotation=(0, 0, 0.6))
    compare_to_cycles(scene, samples=128, max_bounces=6)


def test_every_closure_node_alone_on_a_sphere():
    scene = new_scene(96, 48)
    materials = [
        node_material("Diffuse", "ShaderNodeBsdfDiffuse", Color=(0.8, 0.6, 0.3), Roughness=0.7),
        node_material("Glossy", "ShaderNodeBsdfAnisotropic", Color=(0.8, 0.8, 0.9), Roughness=0.3),
        node_material("Glossy GGX", "ShaderNodeBsdfAnisotropic", Color=(0.9, 0.7, 0.5), Roughness=0.5,
                      opt_distribution="GGX"),
        node_material("Glass", "ShaderNodeBsdfGlass", Color=(1.0, 0.9, 0.8), Roughness=0.15, IOR=1.5),
        node_material("Refraction", "ShaderNodeBsdfRefraction", Color=(0.8, 0.9, 1.0), Roughness=0.0,
                      IOR=1.33, opt_distribution="GGX"),
        node_material("Metallic", "ShaderNodeBsdfMetallic", Roughness=0.25),
        node_material("Conductor", "ShaderNodeBsdfMetallic", Roughness=0.2, opt_fresnel_type="PHYSICAL_CONDUCTOR"),
        node_material("Sheen", "ShaderNodeBsdfSheen", Color=(0.8, 0.7, 0.9), Roughness=0.3),
        node_material("Translucent", "ShaderNodeBsdfTranslucent", Color=(0.7, 0.9, 0.6)),
        node_material("Transparent", "ShaderNodeBsdfTransparent", Color=(0.6, 0.8, 1.0)),
        node_material("Emission", "ShaderNodeEmission", Color=(1.0, 0.6, 0.3), Strength=1.5),
        node_material("Plain", "ShaderNodeBsdfDiffuse", Color=(0.5, 0.5, 0.5)),
    ]
    grid_of_spheres(materials, 6)
    add_camera(scene, (0, -6.5, 1.0), (0, 0, 1.0), lens=40)
    hdri_world(scene, "courtyard.exr", strength=1.0)
    compare_to_cycles(scene, samples=128, max_bounces=6)


def test_beckmann_and_ashikhmin_shirley_distributions():
    """The non-GGX distributions: Beckmann reflection (Glossy, Metallic), refraction and glass, and the
    Ashikhmin-Shirley lobe of the Glossy BSDF."""
    scene = new_scene(96, 48)
    G = "ShaderNodeBsdfAnisotropic"
    materials = [
        node_material("Glossy Beckmann", G, Color=(0.8, 0.8, 0.9), Roughness=0.3, opt_distribution="BECKMANN"),
        node_material("Glossy Ashikhmin-Shirley", G, Color=(0.9, 0.7, 0.5), Roughness=0.3,
                      opt_distribution="ASHIKHMIN_SHIRLEY"),
        node_material("Refraction Beckmann", "ShaderNodeBsdfRefraction", Color=(0.8, 0.9, 1.0), Roughness=0.2,
                      IOR=1.45, opt_distribution="BECKMANN"),
        node_material("Metallic Beckmann", "ShaderNodeBsdfMetallic", Roughness=0.3, opt_distribution="BECKMANN"),
        node_material("Glass Beckmann", "ShaderNodeBsdfGlass", Color=(1.0, 0.9, 0.8), Roughness=0.2, IOR=1.5,
                      opt_distribution="BECKMANN"),
    ]
    grid_of_spheres(materials, 5)
    add_camera(scene, (0, -6.5, 0.5), (0, 0, 0.5), lens=40)
    hdri_world(scene, "courtyard.exr", strength=1.0)
    compare_to_cycles(scene, samples=128, max_bounces=6)


def test_ashikhmin_velvet_sheen():
    """The Sheen BSDF's Ashikhmin distribution (Blender's Velvet BSDF before 4.0, in files of that time): Cycles'
    Ashikhmin velvet lobe, at three roughnesses and mixed with a Diffuse BSDF. Ember rendered it as the
    Microfiber sheen, with a warning: a public car model (mpett/donut_coffee, Blender 2.79) 9% brighter."""
    scene = new_scene(80, 40)
    velvet = "ShaderNodeBsdfSheen"
    materials = [node_material(f"Velvet {r}", velvet, Color=(0.8, 0.3, 0.4), Roughness=r, opt_distribution="ASHIKHMIN")
                 for r in (0.1, 0.5, 1.0)]
    mixed = node_material("Velvet over diffuse", velvet, Color=(0.3, 0.6, 0.9), Roughness=0.4,
                          opt_distribution="ASHIKHMIN")
    tree = mixed.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.5
    tree.links.new(tree.nodes.new("ShaderNodeBsdfDiffuse").outputs[0], mix.inputs[1])
    tree.links.new(out.inputs["Surface"].links[0].from_socket, mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    grid_of_spheres(materials + [mixed], 4)
    add_camera(scene, (0, -6.0, 1.0), (0, 0, 0.5), lens=40)
    hdri_world(scene, "courtyard.exr", strength=1.0)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.rotation_euler = 3.0, (0.9, 0.0, 0.6)
    scene.collection.objects.link(sun)
    compare_to_cycles(scene, samples=128, max_bounces=6)


def test_mix_and_add_shaders_and_a_textured_mix_factor():
    scene = new_scene(64, 48)
    size = 8
    yy, xx = np.mgrid[0:size, 0:size]
    checks = (((xx + yy) % 2) * 0.8 + 0.1).astype(np.float32)
    image = bpy.data.images.new("Checks", size, size, alpha=True, float_buffer=True)
    image.pixels.foreach_set(np.stack([checks] * 3 + [np.ones_like(checks)], -1).ravel())
    image.pack()
    mat = bpy.data.materials.new("Mixed")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    add = tree.nodes.new("ShaderNodeAddShader")
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.2, 0.5, 0.8, 1.0)
    glossy = tree.nodes.new("ShaderNodeBsdfAnisotropic")
    glossy.inputs["Roughness"].default_value = 0.2
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 0.3
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tree.links.new(tex.outputs["Color"], mix.inputs["Fac"])
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(glossy.outputs[0], add.inputs[0])
    tree.links.new(emission.outputs[0], add.inputs[1])
    tree.links.new(add.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    quad_object("Card", (-1.2, 0, 0), (2.4, 0, 0), (0, 0, 2.0), mat)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.6, -1.0, 0.5))
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(mat)
    add_camera(scene, (0, -4.5, 1.0), (0, 0, 1.0), lens=35)
    hdri_world(scene, "forest.exr", strength=1.0)
    compare_to_cycles(scene, samples=128, max_bounces=4)


def test_glass_refracts_a_textured_background():
    scene = new_scene(64, 64)
    size = 16
    yy, xx = np.mgrid[0:size, 0:size]
    checks = (((xx // 2 + yy // 2) % 2) * 0.8 + 0.1).astype(np.float32)
    image = bpy.data.images.new("Board", size, size, alpha=True, float_buffer=True)
    rgba = np.stack([checks, checks * 0.5 + 0.2, 1.0 - checks * 0.8, np.ones_like(checks)], -1)
    image.pixels.foreach_set(rgba.astype(np.float32).ravel())
    image.pack()
    quad_object("Board", (-2, 1.5, -0.5), (4, 0, 0), (0, 0, 3), diffuse_material("Board", image=image))
    glass = node_material("Glass", "ShaderNodeBsdfGlass", Roughness=0.0, IOR=1.5)
    sphere((0, 0, 1.0), glass, radius=0.8)
    add_camera(scene, (0, -4.0, 1.0), (0, 0, 1.0), lens=40)
    set_world(scene, color=(1.0, 1.0, 1.0))
    compare_to_cycles(scene, samples=128, max_bounces=8)


@pytest.mark.parametrize("film_transparent", [False, True])
def test_alpha_cut_card_in_front_of_a_wall(film_transparent):
    """Principled Alpha from an image's alpha channel: rays pass through (transparent bounces), shadows
    too (transparent shadows), and the film's alpha sees partial transparency."""
    scene = new_scene(64, 64)
    scene.render.film_transparent = film_transparent
    size = 16
    yy, xx = np.mgrid[0:size, 0:size]
    alpha = np.where((xx - 7.5) ** 2 + (yy - 7.5) ** 2 < 36, 1.0, 0.0)
    alpha[:, :3] = 0.5  # a half-transparent strip
    image = bpy.data.images.new("Leaf", size, size, alpha=True, float_buffer=True)
    rgba = np.stack([np.full_like(alpha, 0.2), np.full_like(alpha, 0.7), np.full_like(alpha, 0.2), alpha], -1)
    image.pixels.foreach_set(rgba.astype(np.float32).ravel())
    image.pack()
    mat = bpy.data.materials.new("Leaf")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Linear"
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    tree.links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])
    bsdf.inputs["Roughness"].default_value = 0.8
    quad_object("Card", (-0.8, -0.5, 0.2), (1.6, 0, 0), (0, 0, 1.6), mat)
    quad_object("Wall", (-3, 1.0, -1), (6, 0, 0), (0, 0, 4), diffuse_material("Wall", (0.8, 0.8, 0.8)))
    light = bpy.data.lights.new("Sun", "SUN")
    light.energy = 3.0
    light.angle = 0.05
    sun = bpy.data.objects.new("Sun", light)
    sun.rotation_euler = (1.2, 0.0, 0.3)
    scene.collection.objects.link(sun)
    add_camera(scene, (0, -3.5, 1.0), (0, 0, 1.0), lens=40)
    set_world(scene, color=(0.1, 0.1, 0.15))
    compare_to_cycles(scene, samples=128, max_bounces=4)
    if film_transparent:
        from bpy_helpers import render_to_array
        cycles = render_to_array(scene, "CYCLES", 64)[..., 3]
        ember_alpha = render_to_array(scene, "EMBER", 64)[..., 3]
        assert abs(float(cycles.mean()) - float(ember_alpha.mean())) < 0.01


def test_transparent_shadows_off_blocks_shadow_rays_only():
    """Material > Settings > Surface > Transparent Shadows off (Material.use_transparent_shadow): Cycles casts an
    opaque shadow from a half-transparent card whose camera rays still pass it (its shader loses
    SD_HAS_TRANSPARENT_SHADOW), unless the material has a volume. Three cards of Principled Alpha 0.4 in front of
    a wall under a sun: Transparent Shadows on, off, and off with a Volume Absorption (a thin box). Found in a
    public file whose glTF-imported wings (Alpha Blend, shadows opaque) rendered 20-50% too bright."""
    scene = new_scene(48, 32)

    def card(name, x, shadows, volume=False):
        mat = bpy.data.materials.new(name)
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Alpha"].default_value = 0.4
        bsdf.inputs["Base Color"].default_value = (0.8, 0.3, 0.1, 1.0)
        mat.use_transparent_shadow = shadows
        if volume:
            absorb = mat.node_tree.nodes.new("ShaderNodeVolumeAbsorption")
            absorb.inputs["Color"].default_value = (0.2, 0.5, 0.9, 1.0)
            absorb.inputs["Density"].default_value = 4.0
            mat.node_tree.links.new(absorb.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Volume"])
            bpy.ops.mesh.primitive_cube_add(size=1.0, location=(x, -0.4, 1.0), scale=(0.3, 0.1, 0.6))
            bpy.context.active_object.data.materials.append(mat)
        else:
            quad_object(name, (x - 0.3, -0.4, 0.4), (0.6, 0, 0), (0, 0, 1.2), mat)

    card("On", -0.8, True)
    card("Off", 0.0, False)
    card("OffVolume", 0.8, False, volume=True)
    quad_object("Wall", (-3, 0.3, -1), (6, 0, 0), (0, 0, 4), diffuse_material("Wall", (0.8, 0.8, 0.8)))
    add_sun(scene, (1.35, 0.0, 0.25))
    add_camera(scene, (0, -3.5, 1.0), (0, 0, 1.0), lens=40)
    set_world(scene, color=(0.05, 0.05, 0.05))
    compare_to_cycles(scene, samples=64, max_bounces=2, seeds=REPLICATE_SEEDS[:2])


# ---------------------------------------------------------------- normal maps and tangents
def bumps_image(size=32, bumps=3, depth=0.35, tilt=0.3):
    """A Non-Color tangent-space normal map of a grid of round bumps on a slope rising along v (so that a
    mirrored bitangent shows), float pixels, packed."""
    yy, xx = (np.mgrid[0:size, 0:size] + 0.5) / size * bumps
    fx, fy = xx % 1.0 - 0.5, yy % 1.0 - 0.5
    # Height h = depth * cos^2(pi r) inside r < 1/2: the normal is (-dh/dx, -dh/dy, 1) normalized.
    r = np.hypot(fx, fy)
    inside = r < 0.5
    dh_dr = np.where(inside, -depth * np.pi * np.sin(2 * np.pi * r), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        gx, gy = (np.where(r > 0, dh_dr * f / r, 0.0) for f in (fx, fy))
    n = np.stack([-gx, -gy - tilt, np.ones_like(gx)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    image = bpy.data.images.new("Bumps", size, size, alpha=False, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
    image.pixels.foreach_set(np.concatenate([n * 0.5 + 0.5, np.ones((size, size, 1))], -1).astype(np.float32).ravel())
    image.pack()
    return image


def normal_mapped(name, idname, image, strength=1.0, space="TANGENT", **inputs):
    """A one-node material whose Normal input is a Normal Map node reading `image`."""
    mat = node_material(name, idname, **inputs)
    tree = mat.node_tree
    shader = next(n for n in tree.nodes if n.bl_idname == idname)
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    normal_map = tree.nodes.new("ShaderNodeNormalMap")
    normal_map.space = space
    normal_map.inputs["Strength"].default_value = strength
    tree.links.new(tex.outputs["Color"], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], shader.inputs["Normal"])
    return mat


def add_sun(scene, rotation, energy=3.0, angle=0.05):
    light = bpy.data.lights.new("Sun", "SUN")
    light.energy = energy
    light.angle = angle
    sun = bpy.data.objects.new("Sun", light)
    sun.rotation_euler = rotation
    scene.collection.objects.link(sun)
    return sun


def test_normal_mapped_planes_under_a_sun_and_an_hdri():
    """Tangent-space normal maps (MikkTSpace tangents from the UV map) on a diffuse and a glossy plane,
    one of them turned and scaled so that its tangents come through an instance transform."""
    scene = new_scene(64, 48)
    image = bumps_image()
    diffuse = normal_mapped("Bumpy Diffuse", "ShaderNodeBsdfDiffuse", image, Color=(0.7, 0.6, 0.5))
    glossy = normal_mapped("Bumpy Glossy", "ShaderNodeBsdfAnisotropic", image, strength=0.8,
                           Color=(0.9, 0.9, 0.9), Roughness=0.25)
    quad_object("Diffuse", (-2.1, 0, 0), (2, 0, 0), (0, 2, 0), diffuse)
    card = quad_object("Glossy", (0, 0, 0), (1, 0, 0), (0, 1, 0), glossy)
    card.location = (1.2, 0.3, 0.05)
    card.rotation_euler = (0.0, 0.0, 0.5)
    card.scale = (1.6, 1.6, 1.6)
    add_sun(scene, (0.9, 0.0, 0.4))
    add_camera(scene, (0, -1.6, 2.2), (0, 1.0, 0), lens=24)
    hdri_world(scene, "forest.exr", strength=0.6)
    compare_to_cycles(scene, samples=128, max_bounces=4)


def test_normal_maps_on_scaled_objects_a_smooth_box_and_n_gons_as_cycles():
    """Cycles evaluates a tangent-space normal map in object space and turns the result to world space as a normal
    (svm_node_normal_map, object_normal_transform): on an object scaled unevenly a tilt flattens along the squashed
    axis. Found in a public file (AkBar3339/DomBlender: a terrace scaled 0.225 in z, 10% dark blocks). And the
    frame's normal, interpolated across a triangle, is brought to unit length from Blender 5.1 (9d939e158), not
    in 5.0: on a smooth-shaded box, whose corner normals differ by 109 degrees, that changes the tilt by a third.
    Two tilted diffuse slabs, scaled (1, 1, 0.2) and (-0.25, 0.7, 0.7) (mirrored), and a smooth box, under a sun,
    each with its own normal map."""
    scene = new_scene(48, 32)
    image = bumps_image()
    for name, location, scale, rotation in (("Squashed", (-1.2, 0, 0.5), (1.0, 1.0, 0.2), (0.5, 0.3, 0.2)),
                                            ("Stretched", (0.0, 0, 0.5), (-0.25, 0.7, 0.7), (0.9, -0.2, 0.4)),
                                            ("Smooth", (1.2, 0.3, 0.5), (0.8, 0.8, 0.8), (0.5, 0.3, 0.2))):
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=location, rotation=rotation)
        bpy.context.active_object.scale = scale
        if name == "Smooth":
            bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(
            normal_mapped(name, "ShaderNodeBsdfDiffuse", image, Color=(0.8, 0.8, 0.8, 1.0)))
    # A mesh with n-gons (a cylinder's caps), which Blender's calc_tangents refuses: MikkTSpace on its triangles,
    # as Cycles (before, every face's tangent approximated per triangle: its smooth sides 10-20% off).
    bpy.ops.mesh.primitive_cylinder_add(vertices=12, radius=0.35, depth=1.0, end_fill_type="NGON",
                                        location=(0.6, -1.4, -0.1), rotation=(0.2, 1.3, 0.5))
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(normal_mapped("Cylinder", "ShaderNodeBsdfDiffuse", image, Color=(0.8, 0.8, 0.8, 1.0)))
    quad_object("Floor", (-4, -4, -0.5), (8, 0, 0), (0, 8, 0), diffuse_material("Floor", (0.5, 0.5, 0.5)))
    add_sun(scene, (0.6, 0.2, 0.8), energy=4.0)
    add_camera(scene, (0, -4.0, 2.0), (0, 0, 0.4), lens=40)
    set_world(scene, color=(0.05, 0.05, 0.05))
    compare_to_cycles(scene, samples=64, max_bounces=1, seeds=REPLICATE_SEEDS[:2])


def test_anisotropic_metal_with_a_uv_tangent_and_a_normal_mapped_sphere():
    """Principled metal whose anisotropy follows the UV map's tangent (Tangent node, rotated), and a
    normal-mapped plastic sphere (interpolated tangents on a curved, smooth mesh)."""
    scene = new_scene(64, 48)
    metal = node_material("Brushed", "ShaderNodeBsdfPrincipled", Base_Color=(0.9, 0.7, 0.5), Metallic=1.0,
                          Roughness=0.35, Anisotropic=0.9, Anisotropic_Rotation=0.1)
    tree = metal.node_tree
    tangent = tree.nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tree.links.new(tangent.outputs["Tangent"], tree.nodes["Principled BSDF"].inputs["Tangent"])
    plastic = normal_mapped("Bumpy Plastic", "ShaderNodeBsdfPrincipled", bumps_image(bumps=4),
                            Base_Color=(0.2, 0.4, 0.7), Roughness=0.3)
    sphere((-0.55, 0, 0.5), metal, radius=0.5)
    sphere((0.55, 0, 0.5), plastic, radius=0.5)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.4, 0.4, 0.4)))
    add_sun(scene, (0.7, 0.0, -0.6), energy=2.0)
    add_camera(scene, (0, -3.2, 1.1), (0, 0, 0.5), lens=40)
    hdri_world(scene, "courtyard.exr", strength=0.8)
    compare_to_cycles(scene, samples=128, max_bounces=4)


def test_anisotropic_metals_with_the_default_and_a_radial_x_tangent():
    """Without a Tangent node Cycles' anisotropy follows the radial tangent about the object's Z axis; a
    Tangent node in Radial X direction turns it about X (both from Generated coordinates). An arbitrary
    tangent rendered the brushed highlights across the wrong way."""
    scene = new_scene(64, 48)
    default = node_material("Default Tangent", "ShaderNodeBsdfPrincipled", Base_Color=(0.9, 0.7, 0.5),
                            Metallic=1.0, Roughness=0.35, Anisotropic=0.9)
    radial_x = node_material("Radial X", "ShaderNodeBsdfPrincipled", Base_Color=(0.6, 0.7, 0.9),
                             Metallic=1.0, Roughness=0.35, Anisotropic=0.9, Anisotropic_Rotation=0.15)
    tree = radial_x.node_tree
    tangent = tree.nodes.new("ShaderNodeTangent")
    tangent.direction_type, tangent.axis = "RADIAL", "X"
    tree.links.new(tangent.outputs["Tangent"], tree.nodes["Principled BSDF"].inputs["Tangent"])
    sphere((-0.55, 0, 0.5), default, radius=0.5)
    sphere((0.55, 0, 0.5), radial_x, radius=0.5)
    bpy.context.active_object.rotation_euler = (0.4, 0.0, 0.3)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.4, 0.4, 0.4)))
    add_sun(scene, (0.7, 0.0, -0.6), energy=2.0)
    add_camera(scene, (0, -3.2, 1.1), (0, 0, 0.5), lens=40)
    hdri_world(scene, "courtyard.exr", strength=0.8)
    compare_to_cycles(scene, samples=128, max_bounces=4)


def test_constant_normal_and_tangent_inputs():
    """A Normal or Tangent input linked to a program that folds to a constant (here Combine XYZ of constants) is
    that direction: Cycles loads a constant-folded input as a linked one (svm.cpp stack_assign_if_linked,
    constant_folded_in). A plastic card whose normal leans 15 degrees toward a sun (it rendered 41% too dark,
    lit as if unlinked: 20% here) and a brushed metal card whose constant tangent turns its highlight."""
    scene = new_scene(48, 32)
    plastic = node_material("Leaning", "ShaderNodeBsdfPrincipled", Base_Color=(0.8, 0.6, 0.4), Roughness=0.4)
    metal = node_material("Brushed", "ShaderNodeBsdfPrincipled", Base_Color=(0.9, 0.8, 0.6), Metallic=1.0,
                          Roughness=0.3, Anisotropic=0.9)
    for mat, socket, value in ((plastic, "Normal", (0.0, -0.96, 0.27)), (metal, "Tangent", (0.0, 0.0, 1.0))):
        tree = mat.node_tree
        combine = tree.nodes.new("ShaderNodeCombineXYZ")
        for k, v in enumerate(value):
            combine.inputs[k].default_value = v
        tree.links.new(combine.outputs["Vector"], tree.nodes["Principled BSDF"].inputs[socket])
    quad_object("Plastic", (-1.1, 0, 0), (1, 0, 0), (0, 0, 1), plastic)
    quad_object("Metal", (0.1, 0, 0), (1, 0, 0), (0, 0, 1), metal)
    add_sun(scene, (1.0, 0.0, 0.8), energy=3.0)
    add_camera(scene, (0, -3.0, 0.5), (0, 0, 0.5), lens=40)
    set_world(scene, color=(0.1, 0.12, 0.15))
    compare_to_cycles(scene, samples=64, max_bounces=2)


def test_holdout_mixed_half_with_diffuse_cuts_half_the_alpha():
    scene = new_scene(48, 48)
    mat = bpy.data.materials.new("Half Holdout")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = 0.5
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.8, 0.3, 0.2, 1.0)
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(tree.nodes.new("ShaderNodeHoldout").outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    sphere((0, 0, 1.0), mat, radius=0.8)
    quad_object("Wall", (-3, 1.5, -1), (6, 0, 0), (0, 0, 4), diffuse_material("Wall", (0.7, 0.7, 0.7)))
    add_camera(scene, (0, -4.0, 1.0), (0, 0, 1.0), lens=40)
    set_world(scene, color=(0.8, 0.8, 0.9))
    compare_to_cycles(scene, samples=64, max_bounces=3)
    from bpy_helpers import render_to_array
    cycles = render_to_array(scene, "CYCLES", 32)[..., 3]
    ember_alpha = render_to_array(scene, "EMBER", 32)[..., 3]
    assert abs(float(cycles[24, 24]) - 0.5) < 0.02 and abs(float(ember_alpha[24, 24]) - 0.5) < 0.02
    assert abs(float(cycles.mean()) - float(ember_alpha.mean())) < 0.005


def test_gltf_metallic_roughness_texture_through_separate_color():
    """Blender's glTF importer feeds Metallic and Roughness from one packed image through a Separate
    Color node (green = roughness, blue = metallic), with the base colour from another image."""
    scene = new_scene(64, 48)
    size = 16
    yy, xx = np.mgrid[0:size, 0:size]
    packed = np.stack([np.ones((size, size)), (xx + 0.5) / size, (yy // 4 % 2).astype(float), np.ones((size, size))], -1)
    mr = bpy.data.images.new("MetallicRoughness", size, size, alpha=True, float_buffer=True)
    mr.pixels.foreach_set(packed.astype(np.float32).ravel())
    mr.colorspace_settings.name = "Non-Color"
    mr.pack()
    mat = bpy.data.materials.new("glTF")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.9, 0.6, 0.3, 1.0)
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = mr
    separate = tree.nodes.new("ShaderNodeSeparateColor")
    tree.links.new(tex.outputs["Color"], separate.inputs[0])
    tree.links.new(separate.outputs["Green"], bsdf.inputs["Roughness"])
    tree.links.new(separate.outputs["Blue"], bsdf.inputs["Metallic"])
    plane = quad_object("Tile", (-1.2, 0, 0), (2.4, 0, 0), (0, 0, 2.0), mat)
    plane.rotation_euler = (0.3, 0.0, 0.0)
    add_camera(scene, (0, -4.0, 1.0), (0, 0, 1.0), lens=40)
    hdri_world(scene, "forest.exr", strength=1.0)
    compare_to_cycles(scene, samples=128, max_bounces=4)


def test_objects_without_a_material_render_cycles_default_surface():
    """Cycles' default surface is a Principled BSDF with its defaults (specular layer included), not a
    grey diffuse: a plain diffuse made this floor 0.9% darker than Cycles (z = 5.9)."""
    scene = new_scene(48, 32)
    set_world(scene, color=(0.6, 0.7, 0.8), strength=1.0)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)])
    compare_to_cycles(scene, samples=64, max_bounces=4)


@pytest.mark.parametrize("shader", ["ShaderNodeMixShader", "ShaderNodeAddShader"])
def test_two_diffuse_bsdfs_mixed_or_added_in_a_white_furnace(shader):
    """A plane seen straight down under a white sky returns its albedo: 0.5 (grey + red) for the Mix,
    grey + red for the Add. Ember used to keep only one of two Diffuse BSDFs of a material in BSDF
    sampling (24% dark) and only one of them at all when they were batched."""
    scene = new_scene(8, 8)
    set_world(scene, color=(1.0, 1.0, 1.0))
    mat = bpy.data.materials.new("Two Diffuse")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    grey, red = tree.nodes.new("ShaderNodeBsdfDiffuse"), tree.nodes.new("ShaderNodeBsdfDiffuse")
    grey.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    red.inputs["Color"].default_value = (0.9, 0.1, 0.05, 1.0)
    node = tree.nodes.new(shader)
    first = 1 if shader == "ShaderNodeMixShader" else 0
    if first:
        node.inputs[0].default_value = 0.5
    tree.links.new(grey.outputs[0], node.inputs[first])
    tree.links.new(red.outputs[0], node.inputs[first + 1])
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    mesh_object("Plane", [(-500, -500, 0), (500, -500, 0), (500, 500, 0), (-500, 500, 0)], [(0, 1, 2, 3)], mat)
    scene.camera.location, scene.camera.rotation_euler = (0, 0, 2), (0, 0, 0)
    image, variance = replicate_render(scene, "EMBER", 32, max_bounces=2)
    albedo = np.array([0.85, 0.45, 0.425]) * (1 if first else 2)
    mean = image.reshape(-1, 3).mean(axis=0)
    se = np.sqrt(variance.reshape(-1, 3).sum(axis=0)) / (8 * 8)
    assert np.all(np.abs(mean - albedo) < 5 * se + 1e-4), (mean, albedo, se)


def test_clamp_direct_matches_cycles():
    """Clamp Direct on both engines, low enough to cut into the sun's light on diffuse spheres: the same
    biased image. Clamping's bias depends on how each contribution was sampled, so the scene keeps to
    what both engines sample alike: one light, diffuse surfaces, direct light only (bounced light's
    clamping depends on the numbers each engine draws for Russian roulette and lobe choices)."""
    scene = new_scene(48, 32)
    materials = [diffuse_material("White", (0.8, 0.8, 0.8)), diffuse_material("Red", (0.8, 0.2, 0.1))]
    grid_of_spheres(materials, 2)
    add_sun(scene, (0.6, 0.2, -0.7), energy=4.0)
    set_world(scene, color=(0.0, 0.0, 0.0))
    unclamped, _ = replicate_render(scene, "EMBER", 16, max_bounces=0)
    clamped, _ = replicate_render(scene, "EMBER", 16, max_bounces=0, clamp=(0.3, 0.0))
    assert clamped.mean() < 0.95 * unclamped.mean()   # the clamp does cut in
    compare_to_cycles(scene, samples=64, max_bounces=0, clamp=(0.3, 0.0))


def test_filter_glossy_matches_cycles():
    """Filter Glossy 1 on both engines: a near-mirror ball throws a caustic on the floor, which the floor's
    diffuse bounce finds through the ball blurred by the bounce's pdf (Cycles' surface_shader_prepare).
    The blur brightens the image by 0.8%: Ember with the filter matches Cycles with it, Ember without it
    does not (image means, within 3.5 standard errors from the replicates); then the block test. The sun is
    a point (angle 0): a sun with a disc is also found through the sharp ball by the floor's BSDF rays, in
    both engines, and its fireflies would drown the blur's difference."""
    scene = new_scene(48, 32)
    mirror = node_material("Mirror", "ShaderNodeBsdfPrincipled", Base_Color=(0.95, 0.9, 0.8), Metallic=1.0,
                           Roughness=0.02)
    sphere((0, 0, 0.8), mirror, radius=0.8)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.8, 0.8, 0.8)))
    add_sun(scene, (0.5, 0.3, -0.6), energy=6.0, angle=0.0)
    set_world(scene, color=(0.02, 0.02, 0.02))
    n = 48 * 32 * 3

    def mean_and_se(engine, blur):
        image, variance = replicate_render(scene, engine, 128, max_bounces=4, blur_glossy=blur)
        return image.mean(), np.sqrt(variance.sum()) / n
    cycles, se_c = mean_and_se("CYCLES", 1.0)
    blurred, se_b = mean_and_se("EMBER", 1.0)
    sharp, se_s = mean_and_se("EMBER", 0.0)
    assert abs(blurred - cycles) < 3.5 * np.hypot(se_b, se_c), (blurred, cycles, se_b, se_c)
    assert abs(sharp - cycles) > 3.5 * np.hypot(se_s, se_c), (sharp, cycles, se_s, se_c)
    # The caustic makes the image mean heavy-tailed: at 64 samples its noise alone can pass 2%, so the
    # mean's tolerance is 4.5 of its standard errors there (twice the variance of the 128-sample means).
    mean_tol = max(0.02, 4.5 * np.sqrt(2.0) * np.hypot(se_b, se_c) / cycles)
    compare_to_cycles(scene, samples=64, max_bounces=4, blur_glossy=1.0, mean_tol=mean_tol)


def caustics_scene():
    """Glass, metal, glossy, coated and refracting spheres on a floor under a sun: the floor's diffuse
    bounces find the sun through each of them (caustics), and see them by their closures."""
    scene = new_scene(48, 32)
    P = "ShaderNodeBsdfPrincipled"
    materials = [
        node_material("Glass", "ShaderNodeBsdfGlass", Roughness=0.3, IOR=1.5),
        node_material("Clear", P, Base_Color=(0.9, 1.0, 0.9), Transmission_Weight=1.0, Roughness=0.3),
        node_material("Metal", "ShaderNodeBsdfMetallic", Roughness=0.3),
        node_material("Coated", P, Base_Color=(0.7, 0.2, 0.1), Roughness=0.3, Coat_Weight=1.0,
                      Coat_Roughness=0.25),
        node_material("Glossy", "ShaderNodeBsdfAnisotropic", Roughness=0.3),
        node_material("Refraction", "ShaderNodeBsdfRefraction", Roughness=0.3, IOR=1.3),
    ]
    grid_of_spheres(materials, 3)
    add_sun(scene, (0.5, 0.3, -0.6), energy=4.0, angle=0.3)
    set_world(scene, color=(0.05, 0.05, 0.05))
    return scene


@pytest.mark.parametrize("caustics", [(False, False), (False, True), (True, False)],
                         ids=["neither", "refractive-only", "reflective-only"])
def test_caustics_switches_match_cycles(caustics):
    """Cycles' Reflective and Refractive Caustics off: a ray from a diffuse bounce finds no glossy
    reflection, or no refraction, closures where it lands (a Principled BSDF's diffuse then takes the
    light its specular layer would have). Each switch takes light from the floor beyond noise, and Ember
    matches Cycles with it."""
    scene = caustics_scene()
    # The light each switch takes: renders with and without it from the same seeds (the same paths until
    # one meets a closure the switch drops), their difference's mean and standard error over the seeds.
    drops = [render_to_array(scene, "EMBER", 16, seed=seed, max_bounces=4)[..., :3].mean() -
             render_to_array(scene, "EMBER", 16, seed=seed, max_bounces=4, caustics=caustics)[..., :3].mean()
             for seed in range(8)]
    drop, se = np.mean(drops), np.std(drops, ddof=1) / np.sqrt(len(drops))
    assert drop > 4 * se, (drops, se)
    compare_to_cycles(scene, samples=64, max_bounces=4, caustics=caustics)


def test_colours_and_values_linked_into_shader_sockets_emit_as_in_cycles():
    """A colour, vector or value output linked into a shader socket (a Color Ramp into the Material Output, a Value
    into it, an RGB into a Mix Shader): Cycles' ShaderGraph puts an Emission node between (the value as Strength
    under white, a colour as Color at Strength 1). Before, Ember rendered each as grey diffuse, with a warning (a
    public file's Color Ramp into Surface)."""
    from bpy_helpers import export_current
    scene = new_scene(32, 32)
    add_camera(scene, (0, -4, 1.5), (0, 0, 0.5))
    set_world(scene, color=(0.1, 0.1, 0.1))
    quad_object("Floor", (-3, -3, 0), (6, 0, 0), (0, 6, 0), diffuse_material("Floor", (0.7, 0.7, 0.7)))

    def material(name, build):
        mat = bpy.data.materials.new(name)
        tree = mat.node_tree
        tree.nodes.clear()
        build(tree, tree.nodes.new("ShaderNodeOutputMaterial"))
        return mat

    def ramp(tree, out):
        noise, colours = tree.nodes.new("ShaderNodeTexNoise"), tree.nodes.new("ShaderNodeValToRGB")
        colours.color_ramp.interpolation = "CONSTANT"
        colours.color_ramp.elements[0].color, colours.color_ramp.elements[1].color = (0.9, 0.2, 0.1, 1), (0.1, 0.3, 0.9, 1)
        tree.links.new(noise.outputs["Fac"], colours.inputs[0])
        tree.links.new(colours.outputs["Color"], out.inputs["Surface"])

    def value(tree, out):
        node = tree.nodes.new("ShaderNodeValue")
        node.outputs[0].default_value = 2.5
        tree.links.new(node.outputs[0], out.inputs["Surface"])

    def mixed(tree, out):
        mix, diffuse, rgb = (tree.nodes.new(k) for k in ("ShaderNodeMixShader", "ShaderNodeBsdfDiffuse", "ShaderNodeRGB"))
        rgb.outputs[0].default_value, mix.inputs[0].default_value = (0.2, 0.9, 0.3, 1), 0.5
        tree.links.new(diffuse.outputs[0], mix.inputs[1])
        tree.links.new(rgb.outputs[0], mix.inputs[2])
        tree.links.new(mix.outputs[0], out.inputs["Surface"])

    for k, build in enumerate((ramp, value, mixed)):
        quad_object(f"Card{k}", (-2.2 + 1.5 * k, 0, 0.2), (1.2, 0, 0), (0, 0, 1.2), material(build.__name__, build))
    assert not export_current().warnings
    compare_to_cycles(scene, samples=64, max_bounces=3)
