"""The Ray Portal BSDF in the closure mixture and the export: where its sample sends the ray, its weight and
pick probability (Cycles' integrate_surface_ray_portal), what shadow rays see of it, and what the export
reads of its node."""
import numpy as np
import pytest

from ember.kernels.scene import Closure, Materials, Param, Shader
from ember.kernels.shading import Shading
from test_closures import FakeHit

F32 = np.float32


def portal(color=(1.0, 1.0, 1.0), position=None, direction=None, factors=()):
    inputs = (("Color", Param.of(color)),)
    if position is not None:
        inputs += (("Position", Param.of(position)),)
    if direction is not None:
        inputs += (("Direction", Param.of(direction)),)
    return Closure("PORTAL", inputs, (), factors)


def shade(closures, n=8, wo=(0.3, -0.4, 0.8)):
    shading = Shading(Materials((Shader(tuple(closures)),)), [])
    hit = FakeHit(n, wo)
    hit.p = tuple(np.full(n, c, F32) for c in (0.5, -0.25, 0.0))
    return shading, hit, shading.surface(hit).closures


def draw(cs, n, seed=0):
    rng = np.random.default_rng(seed)
    return cs.sample(*(rng.random(n, dtype=F32) for _ in range(4)))


def test_an_unlinked_portal_lets_the_ray_go_straight_on_from_the_hit():
    _, hit, cs = shade([portal(color=(0.9, 0.5, 0.2))])
    s = draw(cs, 8)
    assert s.portal.all() and s.transparent.all() and s.delta.all() and np.isinf(s.pdf).all()
    assert s.origin is None  # from the hit itself: the integrator offsets it as for any surface
    np.testing.assert_allclose(np.stack(s.wi), np.stack(hit.d), atol=1e-7)
    np.testing.assert_allclose(s.weight, np.float32([[0.9], [0.5], [0.2]]).repeat(8, axis=1), rtol=1e-6)
    assert not cs.evaluable().any()  # no light sampling at a portal alone: it has no eval
    f, pdf = cs.eval_at(np.arange(8), tuple(np.broadcast_to(F32(c), 8) for c in (0.0, 0.0, 1.0)))
    assert not f.any() and not pdf.any()


def test_position_and_direction_move_and_turn_the_ray():
    """Direction is normalised; a Position off the hit is the ray's start, exactly; one within Cycles'
    3.2e-5 of the hit is the hit itself."""
    _, hit, cs = shade([portal(position=(1.0, 2.0, 3.0), direction=(0.0, 0.0, -2.0))])
    s = draw(cs, 8)
    np.testing.assert_array_equal(s.origin, np.float32([[1.0], [2.0], [3.0]]).repeat(8, axis=1))
    np.testing.assert_array_equal(np.stack(s.wi), np.float32([[0], [0], [-1]]).repeat(8, axis=1))
    _, _, near = shade([portal(position=(0.5, -0.25, 2e-5))])
    assert draw(near, 8).origin is None


def test_a_portal_mixed_with_diffuse_is_picked_by_its_sample_weight():
    """Mix 0.3: the portal is picked with probability 0.3 / (0.3 + 0.7 x 0.8) and its sample weighs its
    colour over that probability (Cycles' pick_pdf); the diffuse part keeps its light sampling."""
    fac = Param.of(0.3)
    closures = [Closure("DIFFUSE", (("Color", Param.of((0.8, 0.8, 0.8))),), (), ((fac, False),)),
                portal(factors=((fac, True),))]
    n = 40_000
    _, _, cs = shade(closures, n)
    s = draw(cs, n, seed=3)
    p = 0.3 / (0.3 + 0.7 * 0.8)
    share = s.portal.mean()
    assert abs(share - p) < 4 * np.sqrt(p * (1 - p) / n), share
    np.testing.assert_allclose(s.weight[:, s.portal], 0.3 / p, rtol=1e-5)
    assert cs.evaluable().all()


def test_shadow_rays_stop_at_a_portal_unless_a_transparent_closure_shares_the_hit():
    """Cycles' shadow rays: a portal is opaque, but where the shader also has a transparent closure, the
    portal's weight joins the transparency (half Transparent, half portal: everything passes)."""
    half = Param.of(0.5)
    alone, hit, _ = shade([portal()])
    assert not alone.transparent.any()
    mixed, hit, _ = shade([Closure("TRANSPARENT", (("Color", Param.of((1.0, 1.0, 1.0))),), (), ((half, False),)),
                           portal(factors=((half, True),))])
    np.testing.assert_allclose(mixed.transparency(hit), 1.0, rtol=1e-6)
    diffuse, hit, _ = shade([Closure("DIFFUSE", (), (), ((half, False),)), portal(factors=((half, True),))])
    assert not diffuse.transparent.any()


def test_the_export_reads_position_and_direction_only_when_linked():
    pytest.importorskip("bpy")
    from bpy_helpers import camera_only_scene, export_current
    from test_export import add_cube
    from test_parity_bsdf_nodes import portal_material
    camera_only_scene()
    add_cube().data.materials.append(portal_material("Plain"))
    add_cube(location=(3, 0, 0)).data.materials.append(portal_material("Moved", offset=(0, 0, 5),
                                                                       direction=(1, 0, 0)))
    result = export_current()
    plain, moved = (result.scene.materials.shaders[i].closures[0] for i in (1, 2))
    assert plain.kind == moved.kind == "PORTAL"
    assert plain.input("Position") is None and plain.input("Direction") is None
    assert moved.input("Position").link is not None and moved.input("Direction") is not None
    assert not [w for w in result.warnings if "Portal" in w]


def test_a_constant_direction_that_is_not_of_unit_length_is_normalised_with_a_warning():
    pytest.importorskip("bpy")
    from bpy_helpers import camera_only_scene, export_current
    from test_export import add_cube
    from test_parity_bsdf_nodes import portal_material
    camera_only_scene()
    add_cube().data.materials.append(portal_material("Long", direction=(0, 0, 3)))
    add_cube(location=(3, 0, 0)).data.materials.append(portal_material("Unit", direction=(0, 0.6, 0.8)))
    result = export_current()
    warned = [w for w in result.warnings if "Portal" in w]
    assert len(warned) == 1 and "'Long'" in warned[0] and "length 3" in warned[0], warned
