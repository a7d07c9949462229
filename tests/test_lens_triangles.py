"""`reference.trace_lens_triangles`: a lens's caustic by triangles of traced vertices,
spread over the pixels by area: converges as the square of the vertices' spacing, agrees
with photon tracing, keeps a flat slab's light exactly."""

import numpy as np
import pytest

import jaxcaustics as jc
from jaxcaustics import reference
from jaxcaustics.inverse.verify import relative_l2


def bump_lens(light=None, shape=(32, 32)):
    x = (np.arange(16) + 0.5) / 16 * 2 - 1
    xx, yy = np.meshgrid(x, x)
    heights = 1.5e-3 * np.exp(-((xx - 0.2) ** 2 + (yy + 0.1) ** 2) / 0.15)
    return jc.LensScene(
        jc.HeightField(heights, (0.0, 0.1, 0.0, 0.1), "clamp"),
        light if light is not None else jc.DirectionalLight.from_angles(10.0, 30.0),
        jc.PlaneReceiver((-0.02, 0.12, -0.02, 0.12), shape),
        thickness=0.01,
        screen_distance=0.3,
    )


def test_triangles_converge_to_the_photon_trace():
    scene = bump_lens()
    images = {n: reference.trace_lens_triangles(scene, n) for n in (33, 65, 129)}
    # second order: measured 0.039, 0.0075 off the 257^2 grid for 33^2 and 65^2
    # vertices (0.0012 for 129^2)
    far, near = (relative_l2(images[n], images[129]) for n in (33, 65))
    assert near < far / 3.5
    # photons at 1024^2 (2 per 0.1 mm; 0.006 off 2048^2 photons, measured): 0.0028
    # from 129^2 vertices, 0.0024 from 257^2
    photons = reference.trace_lens(scene, 1024)
    assert relative_l2(images[129], photons) < 0.01
    assert images[129].sum() == pytest.approx(photons.sum(), rel=1e-3)


def test_a_flat_slab_gives_its_light_evenly():
    flat = jc.LensScene(
        jc.HeightField(np.zeros((8, 8)), (0.0, 0.1, 0.0, 0.1), "clamp"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver((-0.02, 0.12, -0.02, 0.12), (28, 28)),
        thickness=0.01,
        screen_distance=0.3,
    )
    image = reference.trace_lens_triangles(flat, (9, 13))
    np.testing.assert_allclose(image[4:24, 4:24], 1.0, atol=1e-9)  # the lens's pixels
    assert image.sum() * (0.14 / 28) ** 2 == pytest.approx(0.01, rel=1e-6)  # its area


def test_a_point_light_and_several_indices():
    lamp = bump_lens(jc.PointLight([0.05, 0.05, 1.0], intensity=2.0))
    grey = reference.trace_lens_triangles(lamp, 65)
    photons = reference.trace_lens(lamp, 512)
    assert relative_l2(grey, photons) < 0.03
    colours = jc.LensScene(
        lamp.surface,
        lamp.light,
        lamp.receiver,
        ior=(1.45, 1.5),
        thickness=0.01,
        screen_distance=0.3,
    )
    both = reference.trace_lens_triangles(colours, 33)
    assert both.shape == (32, 32, 2)
    assert relative_l2(both[..., 1], reference.trace_lens_triangles(lamp, 33)) < 1e-12


@pytest.mark.parametrize("bad", [1, (4,), (4, 1), 2.5, True, (1 << 13, 1 << 14)])
def test_bad_vertex_grids_are_refused(bad):
    with pytest.raises(ValueError, match="vertices_per_axis"):
        reference.trace_lens_triangles(bump_lens(), bad)
