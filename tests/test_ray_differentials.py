"""The rays' footprint at indirect hits, which the Bump node, the Wireframe node's Pixel Size and hair coverage read.
From Blender 5.2, Cycles widens a ray's direction spread after each rough bounce to the square root of its
closures' roughness squared, averaged with their pdfs toward the sampled direction (bsdf_widen_dD; a diffuse
bounce: 1 radian); up to 5.1 the camera's pixel spread is kept. A public house, whose walls take a Bump of a Noise
of scale 5000, read its indirect light 12% dark against Blender 5.3 before Ember widened it too (a small scene that
shows it through a render was not found: simple bumped walls lit by a lamp are not sensitive to the footprint)."""
import bpy
import numpy as np

from bpy_helpers import new_scene



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
