"""Volumes against closed forms, through Blender end to end where the scene matters (the kernel alone for the
samplers): a homogeneous slab's transmittance (closed form and null-scattering estimate), white scattering
media in a uniform world (a volume furnace, each phase function), equiangular sampling's pdf and samples,
the volume stack's crossings, and the null-scattering estimator's mean against exp(-optical depth)."""
import math

import numpy as np
import pytest

from bpy_helpers import export_current, mesh_object, new_scene, node_material, render_to_array, set_world

CUBE_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def box(name, lo, hi, material=None):
    verts = [(x, y, z) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    return mesh_object(name, verts, CUBE_FACES, material)


def volume_material(name, kind, surface=None, **inputs):
    """A material with `kind` (a volume node) in its Volume output and, optionally, a surface node: (material,
    the volume node)."""
    options = {("opt_phase" if k == "phase" else k): v for k, v in inputs.items()}
    m = node_material(name, kind, output="Volume", **options)
    tree = m.node_tree
    if surface is not None:
        out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
        tree.links.new(tree.nodes.new(surface).outputs[0], out.inputs["Surface"])
    return m, next(n for n in tree.nodes if n.bl_idname == kind)


def orthographic_view(scene, z=3.0, scale=1.0):
    camera = scene.camera
    camera.location, camera.rotation_euler = (0.0, 0.0, z), (0.0, 0.0, 0.0)
    camera.data.type, camera.data.ortho_scale = "ORTHO", scale


def set_volume_bounces(scene, bounces):
    scene.ember.volume_bounces = bounces
    scene.cycles.volume_bounces = bounces


# ---------------------------------------------------------------- transmittance through a slab
@pytest.mark.parametrize("varying", [False, True])
def test_absorbing_slab_transmits_exp_minus_optical_depth(varying):
    """Looking down through a 0.5 thick absorbing slab at a uniform world: every pixel reads the world times
    exp(-(1 - colour) density 0.5) per channel. Homogeneous: the closed form, exactly. Varying (the density a
    node program computes, constant in value but not in form): ratio tracking's unbiased estimate, within
    five standard errors of the pixels' mean."""
    scene = new_scene(16, 16)
    set_world(scene, color=(1.0, 1.0, 1.0))
    colour, density = np.array([0.2, 0.6, 0.9]), 2.0
    m, node = volume_material("Slab", "ShaderNodeVolumeAbsorption", Color=(*colour, 1.0), Density=density)
    if varying:
        tree = m.node_tree
        noise = tree.nodes.new("ShaderNodeTexNoise")
        zero = tree.nodes.new("ShaderNodeMath")
        zero.operation, zero.inputs[1].default_value = "MULTIPLY", 0.0
        add = tree.nodes.new("ShaderNodeMath")
        add.operation, add.inputs[1].default_value = "ADD", density
        tree.links.new(noise.outputs["Fac"], zero.inputs[0])
        tree.links.new(zero.outputs[0], add.inputs[0])
        tree.links.new(add.outputs[0], node.inputs["Density"])
    box("Slab", (-5, -5, 0.25), (5, 5, 0.75), m)
    orthographic_view(scene)
    expected = np.exp(-(1.0 - colour) * density * 0.5)
    pixels = render_to_array(scene, "EMBER", 64, max_bounces=2)[..., :3].reshape(-1, 3).astype(np.float64)
    if not varying:
        # (The rays enter and leave the slab a ray offset (kernels.interaction.spawn_offset) off its faces.)
        assert np.allclose(pixels, expected, rtol=2e-4), (pixels.mean(axis=0), expected)
        return
    mean, se = pixels.mean(axis=0), pixels.std(axis=0, ddof=1) / math.sqrt(len(pixels))
    assert np.all(np.abs(mean - expected) < 5 * se + 1e-6), (mean, expected, se)
    assert np.all(se < 0.05 * expected)   # an estimate, not a lucky zero


# ---------------------------------------------------------------- the volume furnace
@pytest.mark.parametrize("phase", ["HENYEY_GREENSTEIN", "FOURNIER_FORAND", "DRAINE", "RAYLEIGH", "MIE"])
def test_white_scattering_medium_in_a_uniform_world_is_the_world(phase):
    """A cube of purely scattering medium (optical radius about 1, so paths scatter several times; coloured: its
    channels scatter 0.7x, 1x and 1.3x as often, none absorbs) in a uniform world of radiance 1: whatever the
    phase function, every pixel's expectation is 1 (nothing absorbs, every path ends in the world). Russian roulette and many volume
    bounces keep it unbiased; the tolerance is five standard errors of the image's mean."""
    scene = new_scene(24, 24)
    set_world(scene, color=(1.0, 1.0, 1.0))
    m, node = volume_material("White", "ShaderNodeVolumeScatter", Color=(0.7, 1.0, 1.3, 1.0), Density=2.0,
                              Anisotropy=0.5, phase=phase)
    box("Cloud", (-0.5, -0.5, -0.5), (0.5, 0.5, 0.5), m)
    camera = scene.camera
    camera.location, camera.rotation_euler = (0.0, -2.5, 0.3), (math.radians(83), 0.0, 0.0)
    set_volume_bounces(scene, 256)
    pixels = render_to_array(scene, "EMBER", 64, max_bounces=256)[..., :3].astype(np.float64)
    mean = pixels.reshape(-1, 3).mean(axis=0)
    # Pixels are independent: the standard error of the mean from their spread (0 where every path's estimate
    # is exactly 1, as phase sampling alone gives in a grey medium: the tolerance's floor is float rounding).
    se = pixels.reshape(-1, 3).std(axis=0, ddof=1) / math.sqrt(pixels.size // 3)
    assert np.all(np.abs(mean - 1.0) < 5 * se + 1e-4), (mean, se)
    # The cube is there: where it also absorbs (a Volume Scatter's colour scales its scattering, which stays
    # pure, as in Cycles; an Absorption beside it takes light away), its pixels are darker.
    tree = m.node_tree
    absorb = tree.nodes.new("ShaderNodeVolumeAbsorption")
    mix = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(node.outputs[0], mix.inputs[0])
    tree.links.new(absorb.outputs[0], mix.inputs[1])
    tree.links.new(mix.outputs[0], tree.nodes["Material Output"].inputs["Volume"])
    grey = render_to_array(scene, "EMBER", 16, max_bounces=256)[..., :3]
    assert grey[8:16, 8:16].mean() < 0.9


# ---------------------------------------------------------------- equiangular sampling
def test_equiangular_samples_follow_their_pdf_and_it_integrates_to_one():
    from ember.kernels.media import equiangular
    rng = np.random.default_rng(7)
    n = 200_000
    origins = np.zeros((n, 3))
    dirs = np.tile([1.0, 0.0, 0.0], (n, 1))
    point = np.tile([1.5, 0.4, 0.0], (n, 1))
    t_min, t_max = np.zeros(n), np.full(n, 4.0)
    t, pdf = equiangular.sample(origins, dirs, point, t_min, t_max, rng.random(n))
    assert np.all((t >= 0) & (t <= 4.0)) and np.all(pdf > 0)
    grid = np.linspace(0.0, 4.0, 40001)
    dens = equiangular.pdf(origins[:1].repeat(len(grid), 0), dirs[:1].repeat(len(grid), 0),
                           point[:1].repeat(len(grid), 0), 0.0, 4.0, grid)
    assert abs(((dens[1:] + dens[:-1]) / 2 * np.diff(grid)).sum() - 1.0) < 1e-6   # (NumPy 1.26: no trapezoid)
    assert np.allclose(pdf, equiangular.pdf(origins, dirs, point, t_min, t_max, t), rtol=1e-9)
    # Chi-square of the samples in 40 bins against the pdf's bin masses.
    edges = np.linspace(0.0, 4.0, 41)
    counts, _ = np.histogram(t, edges)
    cdf = np.concatenate([[0.0], np.cumsum((dens[1:] + dens[:-1]) / 2 * np.diff(grid))])
    mass = np.diff(np.interp(edges, grid, cdf))
    chi2 = ((counts - n * mass) ** 2 / (n * mass)).sum()
    assert chi2 < 80.0, chi2   # 39 degrees of freedom: p < 1e-4 beyond 80
    # Against a uniform pdf the same samples fail: the test can tell.
    uniform = np.full(40, 1 / 40)
    assert ((counts - n * uniform) ** 2 / (n * uniform)).sum() > 1000


def test_cone_range_is_where_the_ray_is_inside_the_cone():
    from ember.kernels.media import equiangular
    rng = np.random.default_rng(3)
    n = 2000
    origins = rng.uniform(-3, 3, (n, 3))
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    apex, axis, cos_half = np.zeros((n, 3)), np.tile([0.0, 0.0, -1.0], (n, 1)), np.full(n, math.cos(0.5))
    end = np.full(n, 10.0)
    t0, t1, hit = equiangular.cone_range(origins, dirs, apex, axis, cos_half, end)
    ts = np.linspace(0, 10, 2001)
    for i in range(0, n, 97):
        x = origins[i] + dirs[i] * ts[:, None]
        inside = (x @ axis[i]) >= cos_half[i] * np.linalg.norm(x, axis=1)
        if inside.any():
            assert hit[i]
            assert abs(ts[inside].min() - t0[i]) < 0.01 and abs(ts[inside].max() - t1[i]) < 0.01
        else:
            assert not hit[i] or t1[i] - t0[i] < 0.01


# ---------------------------------------------------------------- the volume stack
def test_volume_stack_enters_once_and_leaves():
    from ember.kernels.media.stack import enter_exit
    stack = np.full((3, 4), -1, np.int32)
    stack[0] = 0                                        # every path in the world's medium
    stack = enter_exit(stack, np.array([2, 2, -1, 5]), np.array([False, True, False, False]))
    assert stack[:, 0].tolist() == [0, 2, -1]          # entered
    assert stack[:, 1].tolist() == [0, -1, -1]         # left a medium it was not in: nothing changes
    assert stack[:, 2].tolist() == [0, -1, -1]         # no medium there
    stack = enter_exit(stack, np.array([2, 7, 7, 5]), np.array([False, False, False, False]))
    assert stack[:, 0].tolist() == [0, 2, -1]          # a medium is on a stack once
    assert stack[:, 3].tolist() == [0, 5, -1]
    stack = enter_exit(stack, np.array([2, -1, -1, 5]), np.array([True, False, False, True]))
    assert stack[:, 0].tolist() == [0, -1, -1] and stack[:, 3].tolist() == [0, -1, -1]


# ---------------------------------------------------------------- null scattering's estimates
class _Slab:
    """A medium stand-in for tracking.track: sigma_t(z) = a + b z, grey, purely absorbing, majorant given."""

    def __init__(self, a, b, majorant, tint=(1.0, 1.0, 1.0), albedo=0.0):
        self.a, self.b, self.bound = a, b, majorant
        self.tint, self.albedo = np.array(tint, np.float32)[:, None], np.float32(albedo)

    def stack_majorant(self, stack):
        return np.full(stack.shape[1], self.bound, np.float32)

    def stack_homogeneous(self, stack):
        return np.zeros(stack.shape[1], bool)

    def stack_coefficients(self, stack, p, d, ray=None, emission=True):
        from ember.kernels.shading.volume import VolumeCoefficients
        sigma = (self.a + self.b * p[:, 2]).astype(np.float32)
        sigma_t = self.tint * sigma[None]
        return VolumeCoefficients(sigma_t * self.albedo, sigma_t, sigma_t * np.float32(0.5), [])


def test_ratio_tracking_is_unbiased_under_a_true_majorant():
    """Transmittance along z through sigma_t = 0.5 + 1.5 z over [0, 1] (optical depth 1.25) and the emission
    gathered (emission 0.5 sigma_t: its integral is 0.5 (1 - T)), estimated by ratio tracking under a majorant
    the medium never exceeds (4): both within five standard errors of the closed forms."""
    from ember.kernels.media.tracking import track
    n = 100_000
    seeds, origins, dirs = _slab_rays(n)
    seg = track(_Slab(0.5, 1.5, 4.0), np.zeros((1, n), np.int32), origins, dirs, np.ones(n, np.float32),
                seeds, np.zeros(n, bool))
    expected = math.exp(-1.25)
    for estimate, truth in ((seg.weight[0].astype(np.float64), expected),
                            (seg.emission[0].astype(np.float64), 0.5 * (1 - expected))):
        se = estimate.std(ddof=1) / math.sqrt(n)
        assert abs(estimate.mean() - truth) < 5 * se, (estimate.mean(), truth, se)


@pytest.mark.parametrize("may_scatter", [False, True])
def test_a_point_above_the_majorant_takes_its_own_extinction_as_cycles_does(may_scatter):
    """Where the medium exceeds the majorant (sigma_t = 0.5 + 1.5 z against 1.5: z > 2/3), Cycles takes the point's
    own extinction as the majorant since the previous collision (volume_integrate_step_scattering): the null
    coefficient is 0 there in a grey medium, so a path ends at its first collision in that part, and the weights
    stay in [0, 1] where negative null weights would swing (a user's glowing disk rendered at 3x Cycles' noise
    and 11% dark at 16 spp). The paths that pass then average Campbell's formula for the Poisson collisions,
    exp(-(integral of sigma_t where z < 2/3) - 1.5 x 1/3) = exp(-7/6): brighter than exp(-1.25), the bias Cycles
    has where its majorant misses a feature. Paths that may scatter choose null events only (no scattering)."""
    from ember.kernels.media.tracking import track
    n = 100_000
    seeds, origins, dirs = _slab_rays(n, 13)
    seg = track(_Slab(0.5, 1.5, 1.5), np.zeros((1, n), np.int32), origins, dirs, np.ones(n, np.float32),
                seeds, np.full(n, may_scatter))
    weight = seg.weight[0].astype(np.float64)
    assert weight.min() >= 0.0 and weight.max() <= 1.0
    assert (seg.emission >= 0).all()
    se = weight.std(ddof=1) / math.sqrt(n)
    assert abs(weight.mean() - math.exp(-7.0 / 6.0)) < 5 * se, (weight.mean(), se)
    assert abs(weight.mean() - math.exp(-1.25)) > 10 * se


def _slab_rays(n, seed=11):
    rng = np.random.default_rng(seed)
    seeds = (rng.integers(0, 2**32, n, dtype=np.uint32), rng.integers(0, 2**32, n, dtype=np.uint32))
    return seeds, np.zeros((n, 3), np.float32), np.tile(np.array([0.0, 0.0, 1.0], np.float32), (n, 1))


def test_paths_that_may_scatter_take_null_events_where_the_medium_only_absorbs():
    """Cycles never samples absorption as an event (volume_scatter_probability): through a medium that only
    absorbs, a path that may scatter takes every collision as a null event, so its weight and the emission it
    gathers are ratio tracking's, number for number. Ending such paths at absorption events is unbiased too, but
    several times noisier where the medium emits (a glowing, absorbing accretion disk read 2.7x Cycles' noise)."""
    from ember.kernels.media.tracking import track
    n = 20_000
    seeds, origins, dirs = _slab_rays(n)
    slab, stack, ends = _Slab(0.5, 1.5, 4.0, tint=(1.0, 0.5, 0.25)), np.zeros((1, n), np.int32), np.ones(n, np.float32)
    free = track(slab, stack, origins, dirs, ends, seeds, np.ones(n, bool))
    plain = track(slab, stack, origins, dirs, ends, seeds, np.zeros(n, bool))
    assert not free.scattered.any()
    np.testing.assert_array_equal(free.weight, plain.weight)
    np.testing.assert_array_equal(free.emission, plain.emission)


@pytest.mark.parametrize("majorant", [4.0, 2.0])
def test_scattering_or_null_events_are_unbiased_in_a_coloured_absorbing_medium(majorant):
    """A medium that scatters 40% of its coloured extinction sigma_t = (1, 0.5, 0.25) (0.5 + 1.5 z) and emits
    0.5 sigma_t: the emission gathered before a path scatters, and the weight of the paths that pass, average
    to the closed forms 0.5 (1 - T) and T per channel, under a loose majorant and one the medium reaches at
    z = 1; every scattering event's weight, 1 / (majorant P_scatter), is positive."""
    from ember.kernels.media.tracking import track
    n = 100_000
    seeds, origins, dirs = _slab_rays(n, 12)
    tint = np.array([1.0, 0.5, 0.25])
    seg = track(_Slab(0.5, 1.5, majorant, tint=tint, albedo=0.4), np.zeros((1, n), np.int32), origins, dirs,
                np.ones(n, np.float32), seeds, np.ones(n, bool))
    assert 0.05 < seg.scattered.mean() < 0.6
    assert (seg.weight[:, seg.scattered] > 0).all()
    passing = np.where(seg.scattered[None], 0.0, seg.weight.astype(np.float64))
    for channel in range(3):
        expected = math.exp(-1.25 * tint[channel])
        for estimate, truth in ((passing[channel], expected),
                                (seg.emission[channel].astype(np.float64), 0.5 * (1 - expected))):
            se = estimate.std(ddof=1) / math.sqrt(n)
            assert abs(estimate.mean() - truth) < 5 * se, (channel, estimate.mean(), truth, se)

def test_volume_outputs_are_read_into_media(tmp_path):
    """A material's Volume output (with a surface and without), and the default volume of a Volume object without
    a material (with its grid attached to its object row), reach the kernel's scene."""
    import bpy
    from ember.engine.export.volumes import openvdb_module
    new_scene(8, 8)
    glass, _ = volume_material("Red glass", "ShaderNodeVolumeAbsorption", "ShaderNodeBsdfGlass",
                               Color=(0.9, 0.2, 0.2, 1.0))
    fog, _ = volume_material("Fog", "ShaderNodeVolumeScatter", Density=0.3, phase="MIE")
    box("Glass", (-1, -1, 0), (0, 0, 1), glass)
    box("Fog", (0.5, 0.5, 0), (1.5, 1.5, 1), fog)
    vdb = openvdb_module()
    if vdb is not None:
        grid = vdb.FloatGrid()
        grid.name = "density"
        grid.copyFromArray(np.ones((4, 4, 4), np.float32), ijk=(0, 0, 0))
        vdb.write(str(tmp_path / "cube.vdb"), grids=[grid])
        volume = bpy.data.volumes.new("Cube")
        volume.filepath = str(tmp_path / "cube.vdb")
        bpy.context.scene.collection.objects.link(bpy.data.objects.new("Cube", volume))
    scene = export_current().scene
    shaders = {s.name: s for s in scene.materials.shaders}
    assert [c.kind for c in shaders["Red glass"].volume] == ["VOLUME_ABSORPTION"]
    assert not shaders["Red glass"].volume_only and shaders["Red glass"].closures
    assert shaders["Fog"].volume_only and dict(shaders["Fog"].volume[0].options)["phase"] == "MIE"
    if vdb is not None:
        assert shaders["default volume"].volume_only
        ((row, grids, scale, step),) = scene.volumes
        assert set(grids) == {"density"} and scale == 1.0 and 0 <= row < len(scene.objects)
        assert step == pytest.approx(1.0)   # its voxels are 1 wide (the biased option's step before the rates)


def test_instanced_volume_meshes_are_media_and_follow_their_instances():
    """Two objects sharing a fog cube's mesh, exported as instances (as the viewport exports every mesh) and as
    plain triangles: the same image within noise (each instance its own medium); after the instances move
    (Renderer.update_instances, the viewport's edit), the image is a fresh build's, bit for bit."""
    import bpy
    from ember.engine.export import export_scene
    from ember.kernels import Renderer, RenderSettings
    scene = new_scene(32, 32)
    set_world(scene, color=(0.3, 0.4, 0.6))
    m, _ = volume_material("Fog", "ShaderNodeVolumeScatter", Color=(0.9, 0.6, 0.3, 1.0), Density=3.0)
    first = box("Fog A", (-0.5, -0.5, 0.5), (0.5, 0.5, 1.5), m)
    second = bpy.data.objects.new("Fog B", first.data)
    scene.collection.objects.link(second)
    second.location = (1.2, 0.0, 0.0)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    settings = RenderSettings(samples=64, max_bounces=4)
    images = {}
    for kind, everything in (("plain", False), ("instanced", True)):
        arrays = export_scene(depsgraph, instance_everything=everything).scene
        assert (arrays.instances is not None) == everything
        with Renderer(arrays, threads=1, processes=False) as renderer:
            assert len(renderer.media) == 2
            images[kind] = renderer.render(settings).image[..., :3].astype(np.float64)
    a, b = images["plain"], images["instanced"]
    blocks = lambda x: x.reshape(4, 8, 4, 8, 3).mean(axis=(1, 3))   # noqa: E731
    # Each 8x8 block's mean: two independent 64-spp estimates, their difference within 5 of its standard
    # errors (from the pixels' spread in the block).
    se = np.sqrt((a.reshape(4, 8, 4, 8, 3).var(axis=(1, 3)) + b.reshape(4, 8, 4, 8, 3).var(axis=(1, 3))) / 64)
    assert (np.abs(blocks(a) - blocks(b)) <= 5 * se + 1e-4).all()
    assert np.abs(a - np.array([0.3, 0.4, 0.6])).max() > 0.1   # the fog is there
    arrays = export_scene(depsgraph, instance_everything=True).scene
    moved = arrays.instances.world_from_object.copy()
    moved[:, 2, 3] += 0.3
    with Renderer(arrays, threads=1, processes=False) as renderer:
        renderer.update_instances(moved)
        updated = renderer.render(settings).image
    import dataclasses
    fresh_scene = dataclasses.replace(arrays, instances=dataclasses.replace(arrays.instances, world_from_object=moved))
    with Renderer(fresh_scene, threads=1, processes=False) as renderer:
        fresh = renderer.render(settings).image
    np.testing.assert_array_equal(updated, fresh)


@pytest.mark.parametrize("majorant", [4.0, 1.5])
def test_shadow_transmittance_by_the_telescoping_estimator(majorant):
    """Shadow rays through the same ramp (optical depth 1.25) take Cycles' telescoping estimator (Misso et al.'s
    unbiased ray marching): its mean within five standard errors of exp(-1.25), whether the range it is given
    bounds the extinction (4) or not (1.5: fewer points, still unbiased), and its spread a fraction of ratio
    tracking's (a few points of the integral instead of a product of random factors)."""
    from ember.kernels.media.tracking import track, transmittance
    n = 100_000
    rng = np.random.default_rng(12)
    seeds = (rng.integers(0, 2**32, n, dtype=np.uint32), rng.integers(0, 2**32, n, dtype=np.uint32))
    origins = np.zeros((n, 3), np.float32)
    dirs = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (n, 1))
    slab, stack, ends = _Slab(0.5, 1.5, majorant), np.zeros((1, n), np.int32), np.ones(n, np.float32)
    estimate = transmittance(slab, stack, origins, dirs, ends, seeds)[0].astype(np.float64)
    se = estimate.std(ddof=1) / math.sqrt(n)
    assert abs(estimate.mean() - math.exp(-1.25)) < 5 * se + 1e-6, (estimate.mean(), se)
    # (The stand-in may emit, so a path segment gathering emission keeps ratio tracking.)
    ratio = track(slab, stack, origins, dirs, ends, seeds, np.zeros(n, bool)).weight[0]
    assert estimate.std() < 0.25 * ratio.astype(np.float64).std(), (estimate.std(), ratio.std())


class _Ramp(_Slab):
    """_Slab marched (the Biased option): every medium varies, step given; scattering as absorbing (albedo)."""

    def __init__(self, a, b, step, albedo=0.0):
        super().__init__(a, b, 0.0)
        self.step, self.albedo = np.array([step]), albedo

    def stack_coefficients(self, stack, p, d, ray=None, emission=True):
        c = super().stack_coefficients(stack, p, d, ray, emission)
        c.sigma_s = c.sigma_t * np.float32(self.albedo)
        return c


def _march(medium, n, length, may_scatter, max_steps, shadow, emission=True):
    from ember.kernels.media.march import Marching
    from ember.kernels.media.tracking import track
    rng = np.random.default_rng(5)
    seeds = (rng.integers(0, 2**32, n, dtype=np.uint32), rng.integers(0, 2**32, n, dtype=np.uint32))
    dirs = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (n, 1))
    return track(medium, np.zeros((1, n), np.int32), np.zeros((n, 3), np.float32), dirs,
                 np.full(n, length, np.float32), seeds, np.full(n, may_scatter), march=Marching(1.0, max_steps),
                 shadow=shadow, emission=emission)


def test_ray_marching_one_step_shades_one_random_point():
    """The Biased option with Max Steps 1: a shadow ray's segment through sigma_t = a + b z over [0, L] is one
    step shaded at a uniform point u, so its transmittance averages exp(-a L) (1 - exp(-b L^2)) / (b L^2),
    not the true exp(-a L - b L^2 / 2); the emission gathered (0.5 sigma_t) averages 0.5 (1 - that). Both within
    five standard errors, and the true transmittance far outside them (the marching's bias, as Cycles')."""
    a, b, length, n = 0.5, 3.0, 1.0, 100_000
    seg = _march(_Ramp(a, b, 0.01), n, length, False, 1, shadow=True)
    marched = math.exp(-a * length) * (1 - math.exp(-b * length ** 2)) / (b * length ** 2)
    estimate = seg.weight[0].astype(np.float64)
    se = estimate.std(ddof=1) / math.sqrt(n)
    assert abs(estimate.mean() - marched) < 5 * se, (estimate.mean(), marched, se)
    assert abs(estimate.mean() - math.exp(-a * length - b * length ** 2 / 2)) > 50 * se
    emitted = seg.emission[0].astype(np.float64)
    assert np.allclose(emitted, 0.5 * (1 - estimate), atol=1e-5)


def test_ray_marching_with_small_steps_converges_on_the_transmittance():
    """Steps of 1/1000 through the same ramp: every path's transmittance is the true one within the steps'
    error (a midpoint-like rule on a linear extinction: under 1e-4), for paths (a random first step) and
    shadow rays alike; a segment longer than Max Steps steps takes longer ones (here 1000 steps of 2/1000 over
    L = 2) and still covers it."""
    a, b = 0.5, 3.0
    for length, max_steps in ((1.0, 1024), (2.0, 1000)):
        truth = math.exp(-a * length - b * length ** 2 / 2)
        for shadow in (False, True):
            seg = _march(_Ramp(a, b, 0.001), 2000, length, False, max_steps, shadow)
            assert np.abs(seg.weight[0] - truth).max() < 1e-4 + 1e-3 * truth, (length, shadow, truth)


def test_ray_marching_scatters_where_the_extinction_says():
    """A white scattering ramp (albedo 1) marched in small steps: a path scatters with probability 1 - T(L), at a
    distance whose distribution is 1 - T(t) (Kolmogorov-Smirnov against the closed form), with weight
    1 / sigma_t at the step's point (the phase closures' sigma_s there make it 1) and weight 1 where it goes
    through; a grey absorbing ramp's paths never scatter and take the transmittance."""
    a, b, length, n = 0.5, 3.0, 1.0, 10_000
    seg = _march(_Ramp(a, b, 0.004, albedo=1.0), n, length, True, 1024, shadow=False)
    t_total = math.exp(-a * length - b * length ** 2 / 2)
    p = 1 - t_total
    assert abs(seg.scattered.mean() - p) < 5 * math.sqrt(p * (1 - p) / n)
    through = ~seg.scattered
    np.testing.assert_allclose(seg.weight[:, through], 1.0, rtol=1e-5)
    t = seg.t[seg.scattered].astype(np.float64)
    sigma = a + b * seg.shade_t[seg.scattered].astype(np.float64)
    np.testing.assert_allclose(seg.weight[0, seg.scattered] * sigma, 1.0, rtol=1e-4)
    assert (np.abs(seg.shade_t[seg.scattered] - t) <= 0.004 + 1e-6).all()   # the event's own step

    t = np.sort(t)
    cdf = (1 - np.exp(-a * t - b * t ** 2 / 2)) / p
    m = len(t)
    distance = max(np.abs(np.arange(1, m + 1) / m - cdf).max(), np.abs(np.arange(m) / m - cdf).max())
    assert distance * math.sqrt(m) < 1.95, distance   # Kolmogorov's 0.1% critical value
    absorbing = _march(_Ramp(a, b, 0.004, albedo=0.0), 2000, length, True, 1024, shadow=False)
    assert not absorbing.scattered.any()
    assert np.abs(absorbing.weight[0] - t_total).max() < 1e-3


def _noise_density(material, node):
    tree = material.node_tree
    noise = tree.nodes.new("ShaderNodeTexNoise")
    tree.links.new(noise.outputs["Fac"], node.inputs["Density"])


def test_biased_option_settings_and_step_sizes():
    """What the Biased option reads, as Cycles: scene.ember's switch, Step Rate (render and viewport) and Max
    Steps into RenderSettings; per medium the step it marches with (Media.step): a tenth of a varying mesh
    medium's mean side times its material's Step Rate, the world's Step Size for a varying world, none (inf) for
    a homogeneous medium."""
    import bpy
    from ember.engine.export import export_scene
    from ember.engine.session import render_settings
    from ember.kernels import Renderer
    scene = new_scene(8, 8)
    set_world(scene, color=(0.2, 0.2, 0.2))
    scene.ember.volume_biased = True
    scene.ember.volume_step_rate, scene.ember.volume_preview_step_rate, scene.ember.volume_max_steps = 2.0, 5.0, 64
    final, viewport = render_settings(scene, None), render_settings(scene, None, viewport=True)
    assert (final.volume_biased, final.volume_step_rate, final.volume_max_steps) == (True, 2.0, 64)
    assert viewport.volume_step_rate == 5.0
    smoke, node = volume_material("Smoke", "ShaderNodeVolumePrincipled")
    _noise_density(smoke, node)
    smoke.cycles.volume_step_rate = 0.5
    box("Smoke", (0, 0, 0), (1, 2, 3), smoke)
    fog, _ = volume_material("Fog", "ShaderNodeVolumeScatter", Density=0.5)
    box("Fog", (3, 0, 0), (4, 1, 1), fog)
    tree = scene.world.node_tree
    world_fog = tree.nodes.new("ShaderNodeVolumePrincipled")
    world_noise = tree.nodes.new("ShaderNodeTexNoise")
    tree.links.new(world_noise.outputs["Fac"], world_fog.inputs["Density"])
    tree.links.new(world_fog.outputs[0], next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld")
                   .inputs["Volume"])
    scene.world.cycles.volume_step_size = 0.25
    arrays = export_scene(bpy.context.evaluated_depsgraph_get()).scene
    with Renderer(arrays, threads=1, processes=False) as renderer:
        media = renderer.media
        names = [("world" if m < 0 else arrays.materials.shaders[m].name) for m in media.material]
        steps = dict(zip(names, media.step))
    assert steps["Smoke"] == pytest.approx(0.1 * 2.0 * 0.5)
    assert steps["world"] == pytest.approx(0.25)
    assert steps["Fog"] == np.inf


class _Coloured:
    """A homogeneous medium whose extinction and albedo differ per colour channel."""
    sigma_t = np.float32([0.3, 0.6, 1.2])
    albedo = np.float32([0.8, 0.5, 0.9])

    def stack_majorant(self, stack):
        return np.full(stack.shape[1], self.sigma_t.max(), np.float32)

    def stack_homogeneous(self, stack):
        return np.ones(stack.shape[1], bool)

    def stack_coefficients(self, stack, p, d, ray=None, emission=True):
        from ember.kernels.shading.volume import VolumeCoefficients
        n = len(p)
        sigma_t = np.repeat(self.sigma_t[:, None], n, 1)
        return VolumeCoefficients(sigma_t * self.albedo[:, None], sigma_t, np.zeros((3, n), np.float32), [])


@pytest.mark.parametrize("rare", [False, True])
def test_homogeneous_scattering_and_passing_weights_are_unbiased(rare):
    """Distance sampling in a coloured homogeneous segment of length L, plain and with the rarer scattering of
    camera rays (RARE_SCATTER_SHARE of 1 - T): the passing paths' weights average T = exp(-sigma_t L) per
    channel, and the scattering ones' weight x sigma_s x t averages the integral of sigma_s exp(-sigma_t t) t
    over [0, L] (the distances' first moment), both within five standard errors; the rarer choice scatters
    about RARE_SCATTER_SHARE as often."""
    from ember.kernels.media.tracking import RARE_SCATTER_SHARE, track
    n, length = 200_000, 2.0
    rng = np.random.default_rng(17)
    seeds = (rng.integers(0, 2**32, n, dtype=np.uint32), rng.integers(0, 2**32, n, dtype=np.uint32))
    dirs = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (n, 1))
    medium = _Coloured()
    seg = track(medium, np.zeros((1, n), np.int32), np.zeros((n, 3), np.float32), dirs,
                np.full(n, length, np.float32), seeds, np.ones(n, bool), rare=np.full(n, rare))
    w = seg.weight.astype(np.float64)
    t = seg.t.astype(np.float64)
    s, a = medium.sigma_t.astype(np.float64), medium.albedo.astype(np.float64)
    passing = np.where(seg.scattered, 0.0, w)
    moment = np.where(seg.scattered, w * (s * a)[:, None] * t, 0.0)
    expected_moment = a * (1 - np.exp(-s * length) * (1 + s * length)) / s
    for estimate, truth in ((passing, np.exp(-s * length)), (moment, expected_moment)):
        se = estimate.std(axis=1, ddof=1) / math.sqrt(n)
        assert (np.abs(estimate.mean(axis=1) - truth) < 5 * se).all(), (estimate.mean(axis=1), truth, se)
    plain = (a / a.sum() * -np.expm1(-s * length)).sum()
    share = seg.scattered.mean() / plain
    assert abs(share - (RARE_SCATTER_SHARE if rare else 1.0)) < 0.02, share
