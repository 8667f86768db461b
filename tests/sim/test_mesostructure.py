"""Mesostructure (docs/simulator.md, "Appearance"): relief finer than the mesh, on synthetic ground truth."""

import cv2
import numpy as np
import pytest

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.appearance import Appearance
from fgcd_drivers.sim.mesostructure import Mesostructure, slope_texture, triangle_tangents
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.scenes import load_scene
from fgcd_drivers.sim.sensor import CameraEffects

INTR = CameraIntrinsics(fx=400.0, fy=400.0, cx=79.5, cy=59.5, width=160, height=120)
LINEAR = CameraEffects(gamma=1.0)


def test_the_slope_texture_has_the_stated_rms_slope():
    meso = Mesostructure(slope_rms=0.2)
    s = slope_texture((256, 256), 0.001, meso, 0)
    assert np.sqrt(np.mean(s[..., 0] ** 2 + s[..., 1] ** 2)) == pytest.approx(0.2, rel=1e-5)
    assert np.all(s[..., 2] == 0)
    assert not np.allclose(s, slope_texture((256, 256), 0.001, meso, 1))  # each part its own field


def test_triangle_tangents_follow_the_texture_axes():
    # u along world x, v along world z (2 m per texture unit): the tangents are x and z whatever the scale
    vertices = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    tri_uv = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    t = triangle_tangents(vertices, np.array([[0, 1, 2]]), tri_uv)
    np.testing.assert_allclose(t[0], [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-7)
    degenerate = triangle_tangents(vertices, np.array([[0, 1, 2]]), np.zeros((1, 3, 2)))
    assert np.all(degenerate == 0)


def _plane(meso: Mesostructure | None):
    scene = load_scene("plane")
    return scene, Renderer(scene, appearance=Appearance(name="test", mesostructure=meso or Mesostructure()))


def test_grain_shading_moves_with_the_light_and_not_with_the_camera():
    scene, rough = _plane(Mesostructure(slope_rms=0.3))
    _, smooth = _plane(None)
    T = scene.default_T_world_cam  # faces the slab squarely, 0.8 m away

    def light_change(renderer):
        a = renderer.render(T, INTR, "led:3", exposure=2.0, effects=LINEAR).gray
        b = renderer.render(T, INTR, "led:9", exposure=2.0, effects=LINEAR).gray
        ratio = np.log(np.maximum(a, 1e-3)) - np.log(np.maximum(b, 1e-3))  # albedo cancels in the ratio
        fine = ratio - cv2.GaussianBlur(ratio, (0, 0), 3.0)  # the lamps' smooth fall-off across the frame out
        return float(np.std(fine[10:-10, 10:-10]))

    # opposite side lights: the grain's flanks swap light and shade, a smooth slab's albedo cancels
    assert light_change(rough) > 3 * light_change(smooth)
    # the camera moved sideways by exactly k pixels' worth: the bent normals move with the surface
    k = 8
    depth = 0.8
    T_moved = T.copy()
    T_moved[:3, 3] += T[:3, 0] * depth * k / INTR.fx
    n_a = rough.render(T, INTR, "front").normals
    n_b = rough.render(T_moved, INTR, "front").normals
    same = n_b[:, :-k] - n_a[:, k:]
    spread = n_a[..., 0].std()
    assert spread > 0.05  # the grain does bend the normals
    assert np.abs(same[..., 0]).mean() < 0.02 * spread  # the wrong way round it is about spread itself
