"""The rays' footprint at indirect hits, which the Bump node, the Wireframe node's Pixel Size and hair coverage read.
From Blender 5.2, Cycles widens a ray's direction spread after each rough bounce to the square root of its
closures' roughness squared, averaged with their pdfs toward the sampled direction (bsdf_widen_dD; a diffuse
bounce: 1 radian); up to 5.1 the camera's pixel spread is kept. A public house, whose walls take a Bump of a Noise
of scale 5000, read its indirect light 12% dark against Blender 5.3 before Ember widened it too (a small scene that
shows it through a render was not found: simple bumped walls lit by a lamp are not sensitive to the footprint).
Camera rays take each their own spread, as Cycles' do: a pixel's angle shrinks toward the frame's edges."""
import math

import bpy
import numpy as np

from bpy_helpers import add_camera, add_lamp, mesh_object, new_scene, render_to_array, set_world


def test_camera_rays_spread_by_their_own_pixel_angle():
    """Cycles' compact differential of a perspective camera ray (camera_sample_perspective): the mean of the lengths
    by which the unit direction moves one pixel right and one pixel up, and a position spread that grows from 0 at
    the eye. At the centre of the frame that is the pixel's size on the plane at distance 1; at a point (x, y) of that
    plane the derivative of the unit direction shrinks the steps to sqrt(1 + y^2) / (1 + x^2 + y^2) and
    sqrt(1 + x^2) / (1 + x^2 + y^2) of it (a 3:2 frame's corner under an 18 mm lens: 0.54x); the near plane's
    origins start at dd x their distance from the eye."""
    from ember.kernels.camera import differentials, generate_rays, view_plane
    from ember.kernels.scene import Camera
    camera = Camera(world_from_camera=np.eye(4, dtype=np.float32), fov_rad=2 * math.atan(18 / 18), width=300,
                    height=200, clip_start=0.25)
    xmin, xmax, ymin, ymax = view_plane(camera)
    pixel = (xmax - xmin) / camera.width
    assert math.isclose(pixel, (ymax - ymin) / camera.height, rel_tol=1e-6)
    x = np.array([0.0, xmax, 0.0, xmax], np.float32)
    y = np.array([0.0, 0.0, ymax, ymax], np.float32)
    dp, dd = differentials(camera, x, y)
    r2 = 1.0 + x.astype(np.float64) ** 2 + y ** 2
    expected = pixel * 0.5 * (np.sqrt(1 + y ** 2.0) + np.sqrt(1 + x ** 2.0)) / r2
    np.testing.assert_allclose(dd, expected, rtol=5e-3)
    assert dd[3] < 0.65 * dd[0]
    np.testing.assert_allclose(dp, dd * 0.25 * np.sqrt(r2), rtol=1e-5)
    # generate_rays hands them over for the view-plane points of its rays (the frame's centre and corner pixels).
    *_, (dp2, dd2) = generate_rays(camera, np.array([100, 0]), np.array([150, 299]), np.zeros(2, np.float32),
                                   np.zeros(2, np.float32), spread=True)
    np.testing.assert_allclose(dd2[0], pixel, rtol=1e-3)
    assert dd2[1] < 0.65 * dd2[0]


def test_panorama_rays_spread_by_their_own_pixel_angle():
    """An equirectangular frame of 360 x 180 pixels over the whole sphere: one pixel right turns a ray at latitude
    phi by 2 pi / 360 x cos(phi), one pixel up by pi / 180, so Cycles' compact differential (camera_sample_panorama)
    is their mean, smaller toward the poles; the near clip plane's origins start at Clip Start x dd."""
    from ember.kernels.camera import generate_rays
    from ember.kernels.scene import Camera
    params = dict(latitude_min=-math.pi / 2, latitude_max=math.pi / 2, longitude_min=-math.pi, longitude_max=math.pi)
    camera = Camera(kind="PANO", panorama_type="EQUIRECTANGULAR", panorama=params, width=360, height=180,
                    clip_start=0.5)
    camera.validate()
    rows = np.array([90, 30, 10])            # latitudes 0, 60 and 80 degrees (pixel centres: +0.5)
    half = np.full(3, 0.5, np.float32)
    *_, (dp, dd) = generate_rays(camera, rows, np.array([100, 100, 100]), half, half, spread=True)
    latitude = np.radians(90.0 - (rows + 0.5))
    step = math.radians(1.0)
    expected = 0.5 * (step * np.cos(latitude) + step)
    np.testing.assert_allclose(dd, expected, rtol=1e-2)
    np.testing.assert_allclose(dp, 0.5 * dd, rtol=1e-5)


def test_a_noisy_bump_under_a_wide_lens_matches_cycles():
    """A floor whose Bump (Filter Width 1) reads a Noise finer than a pixel's footprint, under a 14 mm lens: the bump's
    steps are each ray's footprint, so where a pixel's angle is smaller (toward the frame's edges) the steps are
    shorter and the normals steeper. With the centre's spread for every ray Ember rendered it 5.7% bright (a user's
    sand under a 50 mm lens 0.7%)."""
    from test_light_linking import within_noise
    scene = new_scene(48, 32)
    add_camera(scene, (0, -5, 2.0), (0, 0, 0), lens=14.0)
    set_world(scene, color=(0.05, 0.05, 0.05))
    mat = bpy.data.materials.new("Bumped")
    tree = mat.node_tree
    tree.nodes.clear()
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value, noise.inputs["Detail"].default_value = 40.0, 2.0
    bump = tree.nodes.new("ShaderNodeBump")
    bump.inputs["Filter Width"].default_value, bump.inputs["Distance"].default_value = 1.0, 1.0
    tree.links.new(tree.nodes.new("ShaderNodeTexCoord").outputs["Object"], noise.inputs["Vector"])
    tree.links.new(noise.outputs["Fac"], bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], diffuse.inputs["Normal"])
    tree.links.new(diffuse.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    mesh_object("Floor", [(-30, -30, 0), (30, -30, 0), (30, 30, 0), (-30, 30, 0)], [(0, 1, 2, 3)], mat)
    add_lamp(scene, "Sun", "SUN", (0, 0, 5), rotation=(math.radians(70), 0, math.radians(30)), energy=3.0)
    pairs = {engine: [render_to_array(scene, engine, 16, seed=s)[..., :3].astype(np.float64) for s in (1, 2)]
             for engine in ("CYCLES", "EMBER")}
    (c1, c2), (e1, e2) = pairs["CYCLES"], pairs["EMBER"]
    within_noise((e1 + e2) / 2, (e1 - e2) ** 2 / 4, (c1 + c2) / 2, (c1 - c2) ** 2 / 4)



def test_renders_widen_differentials_from_blender_5_2():
    """The render settings follow the running Blender's Cycles: widened from 5.2 on, the camera's spread before."""
    from ember.engine.session import render_settings
    scene = new_scene(8, 8)
    assert render_settings(scene, None).widen_differentials == (bpy.app.version >= (5, 2, 0))


def test_the_average_roughness_weighs_closures_by_their_pdfs():
    """ClosureSet.average_roughness_squared: a Lambert closure counts 1, a GGX one alpha_x alpha_y, each weighted by
    its pdf toward the direction times its sample weight (Cycles' _surface_shader_bsdf_eval_mis); a lone closure
    is its own roughness; a singular one counts 0."""
    from ember.kernels.bsdf import closures, lobes
    wo = np.array([[0.3], [0.0], [1.0]], np.float32)
    wo /= np.linalg.norm(wo)
    wi = np.array([-0.3, 0.0, 1.0], np.float32) / np.float32(np.hypot(0.3, 1.0))   # the mirror direction
    one = np.array([0])

    def made(*specs):
        ns = (np.zeros(1, np.float32), np.zeros(1, np.float32), np.ones(1, np.float32))
        b = closures.ClosureBuilder(1, ns, tuple(wo))
        for lobe, alpha, weight in specs:
            extra = {} if lobe == lobes.LAMBERT else dict(ax=alpha, ay=alpha, eta=1.5)
            b.add(lobe, one, np.full((3, 1), weight, np.float32), **extra)
        return b.finish()

    direction = tuple(np.array([c]) for c in wi)
    assert made((lobes.LAMBERT, 0, 1.0)).average_roughness_squared(one, direction)[0] == 1.0
    glossy = made((lobes.REFLECTION, 0.3, 1.0))
    np.testing.assert_allclose(glossy.average_roughness_squared(one, direction), 0.09, rtol=1e-6)
    mixed = made((lobes.LAMBERT, 0, 0.5), (lobes.REFLECTION, 0.3, 0.5))
    f, pdf_lambert = made((lobes.LAMBERT, 0, 1.0)).eval_at(one, direction)
    f, pdf_glossy = glossy.eval_at(one, direction)
    expected = (pdf_lambert * 1.0 + pdf_glossy * 0.09) / (pdf_lambert + pdf_glossy)   # equal sample weights
    np.testing.assert_allclose(mixed.average_roughness_squared(one, direction), expected, rtol=1e-5)
    assert 0.09 < expected[0] < 0.5   # toward the mirror direction the sharp lobe's pdf dominates
    mirror = made((lobes.REFLECTION, 0.0, 1.0))
    assert mirror.average_roughness_squared(one, direction)[0] == 0.0
