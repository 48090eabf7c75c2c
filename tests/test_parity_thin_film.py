"""Thin-film iridescence against Cycles (CPU, no clamping, box filter): the Principled BSDF's specular,
metal and transmission layers, the Glass BSDF and the Metallic BSDF (F82 and physical conductor) under a
film, with constant and node-driven thickness.

Same method as test_parity_materials: four seed replicates per engine; the whole-image mean within 2% and
every block of an 8x8 grid within 4.5 standard errors of the difference.
"""
import bpy

from bpy_helpers import add_camera, compare_to_cycles, export_current, hdri_world, new_scene, node_material
from test_parity_materials import grid_of_spheres

P = "ShaderNodeBsdfPrincipled"


def _scene():
    scene = new_scene(48, 48)
    add_camera(scene, (0, -4.4, 1.0), (0, 0, 1.0), lens=45)
    hdri_world(scene, "courtyard.exr", strength=1.0)
    return scene


def _light(scene):
    data = bpy.data.lights.new("Lamp", "POINT")
    data.energy, data.shadow_soft_size = 300.0, 0.3
    lamp = bpy.data.objects.new("Lamp", data)
    scene.collection.objects.link(lamp)
    lamp.location = (1.5, -3.0, 3.0)


def test_principled_dielectric_and_glass_under_a_film():
    """A dark plastic under a soap film (500 nm, IOR 1.33; its Specular Tint scales the film's F0), one whose film is thinner than 1 nm (the IOR
    blend), a clear glass with a film (transmission: its back faces divide the film IOR) and a film with no
    specular layer under it (IOR Level 0: Cycles makes the layer for the film alone)."""
    scene = _scene()
    materials = [
        node_material("Soap", P, Base_Color=(0.02, 0.02, 0.03), Roughness=0.05, Thin_Film_Thickness=500.0,
                      Thin_Film_IOR=1.33, Specular_Tint=(0.7, 0.85, 1.0)),
        node_material("Thinnest", P, Base_Color=(0.1, 0.1, 0.4), Roughness=0.2, Thin_Film_Thickness=0.6,
                      Thin_Film_IOR=2.0),
        node_material("Filmed glass", P, Transmission_Weight=1.0, Roughness=0.0, Thin_Film_Thickness=350.0,
                      Thin_Film_IOR=1.8),
        node_material("Film only", P, Base_Color=(0.05, 0.05, 0.05), Specular_IOR_Level=0.0, Roughness=0.15,
                      Thin_Film_Thickness=700.0, Thin_Film_IOR=1.5),
    ]
    grid_of_spheres(materials, 2)
    _light(scene)
    compare_to_cycles(scene, samples=96, max_bounces=6)


def test_glass_and_metallic_bsdfs_under_a_film():
    """Glass BSDF (rough, GGX multiscatter), Metallic BSDF F82 (Principled-like metal too) and physical
    conductor, each with its own film; the Principled metal's thickness comes from a node program."""
    scene = _scene()
    metal = node_material("Principled metal", P, Base_Color=(0.9, 0.6, 0.4), Metallic=1.0, Roughness=0.25,
                          Specular_Tint=(0.9, 0.9, 1.0), Thin_Film_IOR=1.6)
    tree = metal.node_tree
    coords = tree.nodes.new("ShaderNodeTexCoord")
    sep = tree.nodes.new("ShaderNodeSeparateXYZ")
    ramp = tree.nodes.new("ShaderNodeMapRange")
    ramp.inputs["To Min"].default_value, ramp.inputs["To Max"].default_value = 200.0, 900.0
    tree.links.new(coords.outputs["Generated"], sep.inputs[0])
    tree.links.new(sep.outputs["Z"], ramp.inputs["Value"])
    tree.links.new(ramp.outputs["Result"], tree.nodes["Principled BSDF"].inputs["Thin Film Thickness"])
    materials = [
        node_material("Filmed Glass BSDF", "ShaderNodeBsdfGlass", Color=(1.0, 0.95, 0.9), Roughness=0.2,
                      IOR=1.5, Thin_Film_Thickness=420.0, Thin_Film_IOR=1.4),
        node_material("Oxide F82", "ShaderNodeBsdfMetallic", Base_Color=(0.8, 0.8, 0.8), Roughness=0.15,
                      Thin_Film_Thickness=300.0, Thin_Film_IOR=2.2),
        node_material("Oxide conductor", "ShaderNodeBsdfMetallic", Roughness=0.1, Thin_Film_Thickness=250.0,
                      Thin_Film_IOR=1.5, opt_fresnel_type="PHYSICAL_CONDUCTOR"),
        metal,
    ]
    grid_of_spheres(materials, 2)
    _light(scene)
    compare_to_cycles(scene, samples=96, max_bounces=6)


def test_film_inputs_are_read_and_not_warned():
    """The three nodes' Thin Film inputs become the closures' inputs (constant or program), with no warning."""
    scene = _scene()
    grid_of_spheres([node_material("A", P, Thin_Film_Thickness=500.0, Thin_Film_IOR=1.4),
                     node_material("B", "ShaderNodeBsdfGlass", Thin_Film_Thickness=300.0),
                     node_material("C", "ShaderNodeBsdfMetallic", Thin_Film_Thickness=200.0)], 3)
    arrays = export_current()
    assert not [w for w in arrays.warnings if "Thin Film" in w], arrays.warnings
    seen = {}
    for shader in arrays.scene.materials.shaders:
        for closure in shader.closures:
            thickness, ior = closure.input("Thin Film Thickness"), closure.input("Thin Film IOR")
            if thickness is not None:   # the default surface and the floor have none
                seen[closure.kind] = (thickness.value[0], ior.value[0])
    assert seen["PRINCIPLED"][0] == 500.0 and abs(seen["PRINCIPLED"][1] - 1.4) < 1e-6
    assert seen["GLASS"][0] == 300.0 and seen["METALLIC"][0] == 200.0
