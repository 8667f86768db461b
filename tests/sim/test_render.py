"""Renderer against analytic cases: depth of a plane and a sphere, Lambert shading, shadows, distortion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fgcd_core.camera import CameraIntrinsics
from fgcd_drivers.sim.appearance import WORLD_ENV
from fgcd_drivers.sim.lights import Light, Lighting
from fgcd_drivers.sim.meshes import MeshPart
from fgcd_drivers.sim.render import Renderer
from fgcd_drivers.sim.sensor import CameraEffects
from fgcd_drivers.sim.transforms import look_at

LINEAR = CameraEffects(gamma=1.0)


@pytest.fixture(autouse=True)
def _smooth_world(monkeypatch):
    """These tests check Lambert shading, shadows and inverse-square fall-off against analytic values of the Lambert model: the smooth
    world. The calibrated world's grain and lobe have their own tests (test_appearance, test_mesostructure)."""
    monkeypatch.setenv(WORLD_ENV, "smooth")


def _rays_world(intr, T, dist=None):
    uu, vv = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    if dist is None:
        xy = np.stack([(uu - intr.cx) / intr.fx, (vv - intr.cy) / intr.fy], -1)
    else:
        pts = np.stack([uu.ravel(), vv.ravel()], 1).reshape(-1, 1, 2)
        xy = cv2.undistortPointsIter(
            pts, intr.K, np.asarray(dist), None, None, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
        ).reshape(vv.shape + (2,))
    d_cam = np.concatenate([xy, np.ones(vv.shape + (1,))], -1)
    return d_cam @ T[:3, :3].T, T[:3, 3]


def test_plane_depth_is_analytic(factories, small_intr):
    scene = factories.make_scene([factories.plane_part()])
    T = look_at((0.3, -1.2, 1.1), (0.0, 0.0, 0.9))  # oblique view
    res = Renderer(scene).render(T, small_intr, None, want=("depth",))
    d, o = _rays_world(small_intr, T)
    # plane y = 0: o_y + t d_y = 0 and the rays have camera-z 1, so t is z-depth
    t = -o[1] / d[..., 1]
    assert np.all(res.depth > 0)
    np.testing.assert_allclose(res.depth, t, rtol=0, atol=2e-6 * t.max())


def test_sphere_depth_is_analytic(sphere_scene, small_intr):
    T = sphere_scene.default_T_world_cam
    res = Renderer(sphere_scene).render(T, small_intr, None, want=("depth",))
    d, o = _rays_world(small_intr, T)
    c, r = np.array([0.0, 0.0, 1.0]), 0.5
    oc = o - c
    a = np.einsum("...i,...i", d, d)
    b = 2 * np.einsum("...i,i", d, oc)
    disc = b * b - 4 * a * (oc @ oc - r * r)
    hit = disc > 0
    t = np.where(hit, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), 0)
    # the mesh is a 1-degree tessellation: chord sag r (1 - cos 0.5 deg) = 19 um; allow for oblique rays
    sag = r * (1 - np.cos(np.radians(0.5)))
    p = o + t[..., None] * d
    n = (p - c) / r
    cos_inc = np.abs(np.einsum("...i,...i", n, d)) / np.sqrt(a)
    core = hit & (cos_inc > 0.5)
    assert core.sum() > 1000
    assert np.all(res.depth[core] > 0)
    err = np.abs(res.depth[core] - t[core])
    assert err.max() < 2.5 * sag / 0.5
    # silhouette: no hits clearly outside the analytic disc
    assert not np.any((res.depth > 0) & (disc < -0.02 * np.abs(b) ** 2))


def test_lambert_shading_of_known_normal(factories, small_intr):
    albedo = 0.6
    scene = factories.make_scene([factories.plane_part(albedo=albedo)])
    T = look_at((0.0, -1.0, 1.0), (0.0, 0.0, 1.0))
    theta = np.radians(50.0)
    to_light = np.array([np.sin(theta), -np.cos(theta), 0.0])  # the plane's normal is -y
    light = Lighting(
        name="t",
        lights=(Light(kind="directional", frame="world", direction=tuple(to_light), intensity=0.8),),
        ambient=0.1,
    )
    res = Renderer(scene).render(T, small_intr, light, exposure=1.0, effects=LINEAR, want=("gray",))
    expected = albedo * (0.1 + 0.8 * np.cos(theta))
    np.testing.assert_allclose(res.gray, expected, atol=2e-3)


def test_point_light_inverse_square(factories, small_intr):
    scene = factories.make_scene([factories.plane_part(albedo=0.5)])
    T = look_at((0.0, -1.0, 1.0), (0.0, 0.0, 1.0))
    light = Lighting(
        name="t",
        lights=(Light(kind="point", frame="camera", position=(0, 0, 0), intensity=1.0, reference_distance_m=1.0),),
        ambient=0.0,
    )
    res = Renderer(scene).render(T, small_intr, light, exposure=1.0, effects=LINEAR, want=("gray",))
    d, o = _rays_world(small_intr, T)
    t = res.depth
    p = o + t[..., None] * d
    dist = np.linalg.norm(p - o, axis=-1)
    cos = (p[..., 1] - o[1]) / dist  # the plane normal is -y, the light is on the -y side
    np.testing.assert_allclose(res.gray, 0.5 * cos / dist**2, rtol=3e-3)


def test_cast_shadow_where_geometry_occludes(factories):
    intr = CameraIntrinsics(fx=100.0, fy=100.0, cx=49.5, cy=49.5, width=100, height=100)
    # a 20 cm cube 30 cm in front of the wall; light straight along the wall normal from the camera side
    v, t, uv = factories.box(center=(0.0, -0.4, 1.0), size=(0.2, 0.2, 0.2))
    cube = MeshPart(
        name="cube",
        label=2,
        vertices=v,
        triangles=t,
        tri_uv=uv,
        texture=factories.uniform_texture(0.5),
        texel_size_m=0.1,
        smooth=False,
    )
    scene = factories.make_scene([factories.plane_part(albedo=0.5), cube])
    T = look_at((0.6, -1.5, 1.0), (0.0, 0.0, 1.0))  # from the side so the shadow is visible next to the cube
    light = Lighting(
        name="t", lights=(Light(kind="directional", frame="world", direction=(0, -1, 0), intensity=1.0),), ambient=0.2
    )
    res = Renderer(scene).render(T, intr, light, exposure=1.0, effects=LINEAR, want=("gray",))
    d, o = _rays_world(intr, T)
    p = o + res.depth[..., None] * d
    on_wall = res.labels == 1
    # the cube's shadow on the wall is the square |x| < 0.1, |z - 1| < 0.1 (light along -y... from -y)
    in_shadow = on_wall & (np.abs(p[..., 0]) < 0.09) & (np.abs(p[..., 2] - 1.0) < 0.09)
    lit = on_wall & ((np.abs(p[..., 0]) > 0.12) | (np.abs(p[..., 2] - 1.0) > 0.12))
    assert in_shadow.sum() > 20 and lit.sum() > 100
    np.testing.assert_allclose(res.gray[in_shadow], 0.5 * 0.2, atol=2e-3)
    np.testing.assert_allclose(res.gray[lit], 0.5 * 1.2, atol=2e-3)


def test_distorted_camera_rays_follow_opencv(factories):
    intr = CameraIntrinsics(
        fx=80.0, fy=80.0, cx=40.2, cy=29.1, width=80, height=60, dist=(-0.2, 0.05, 0.001, -0.001, 0.0)
    )
    scene = factories.make_scene([factories.plane_part()])
    T = look_at((0.2, -1.0, 1.0), (0.0, 0.0, 1.1))
    res = Renderer(scene).render(T, intr, None, want=("depth",))
    d, o = _rays_world(intr, T, dist=intr.dist)
    t = -o[1] / d[..., 1]
    np.testing.assert_allclose(res.depth, t, atol=1e-5)


def test_supersampling_keeps_flat_shading_and_antialiases_edges(factories, small_intr):
    scene = factories.make_scene([factories.plane_part(albedo=0.5, size=0.5)])
    T = look_at((0.05, -1.0, 1.03), (0.0, 0.0, 1.0))
    light = Lighting(name="a", lights=(), ambient=1.0)
    r1 = Renderer(scene).render(T, small_intr, light, exposure=1.0, effects=LINEAR, want=("gray",))
    r3 = Renderer(scene, supersample=3).render(T, small_intr, light, exposure=1.0, effects=LINEAR, want=("gray",))
    inner = r1.labels == 1
    inner = cv2.erode(inner.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    np.testing.assert_allclose(r3.gray[inner], 0.5, atol=1e-3)
    # edge pixels get intermediate values with supersampling, never with one ray per pixel
    assert set(np.unique(np.round(r1.gray, 3))) <= {0.0, 0.5}
    partial = (r3.gray > 0.05) & (r3.gray < 0.45)
    assert partial.sum() > 10


def test_camera_effects_vignetting_and_noise(factories, small_intr):
    scene = factories.make_scene([factories.plane_part(albedo=0.5, size=20.0)])
    T = look_at((0.0, -0.5, 1.0), (0.0, 0.0, 1.0))
    light = Lighting(name="a", lights=(), ambient=0.6)
    r = Renderer(scene)
    vig = r.render(T, small_intr, light, exposure=1.0, effects=CameraEffects(gamma=1.0, vignetting=0.3), want=("gray",))
    assert vig.gray[0, 0] == pytest.approx(0.3 * 0.7, abs=2e-3)
    assert vig.gray[29, 39] == pytest.approx(0.3, abs=2e-3)
    eff = CameraEffects(gamma=1.0, read_noise=0.01, shot_noise=0.02)
    noisy = r.render(T, small_intr, light, exposure=1.0, effects=eff, rng=np.random.default_rng(1), want=("gray",))
    sigma = np.sqrt(0.01**2 + 0.02**2 * 0.3)
    # 4800 samples: the std estimate is good to ~1 % (1/sqrt(2n)); allow 8 %
    assert np.std(noisy.gray - 0.3) == pytest.approx(sigma, rel=0.08)
    again = r.render(T, small_intr, light, exposure=1.0, effects=eff, rng=np.random.default_rng(1), want=("gray",))
    np.testing.assert_array_equal(noisy.gray, again.gray)


def test_bilinear_texture_sampling_with_wrap(factories, small_intr):
    """Albedo under pure ambient light is the texture bilinearly interpolated at the hit's (u, v), tiles wrapping."""
    rng = np.random.default_rng(5)
    tex = np.repeat(rng.uniform(0.2, 0.8, (16, 16, 1)), 3, axis=2).astype(np.float32)
    part = factories.plane_part()
    part = MeshPart(
        name="plane",
        label=1,
        vertices=part.vertices,
        triangles=part.triangles,
        tri_uv=part.tri_uv,
        texture=tex,
        texel_size_m=part.texel_size_m,
        smooth=False,
    )
    scene = factories.make_scene([part])
    # frontal, 1 m away: a pixel covers 12.5 mm, a texel 31 mm (mip level 0); the view centre is a tile corner
    T = look_at((0.0, -1.0, 1.0), (0.0, 0.0, 1.0))
    res = Renderer(scene).render(
        T, small_intr, Lighting(name="a", lights=(), ambient=1.0), exposure=1.0, effects=LINEAR, want=("gray",)
    )
    d, o = _rays_world(small_intr, T)
    p = o + (-o[1] / d[..., 1])[..., None] * d
    u = (p[..., 0] + 2.0) / 0.5  # plane_part: origin (-2, 0, -1), 0.5 m per texture repeat, v runs down z
    v = -(p[..., 2] + 1.0) / 0.5
    x = (u - np.floor(u)) * 16 - 0.5
    y = (v - np.floor(v)) * 16 - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    g = tex[..., 0].astype(float)

    def at(yy, xx):
        return g[yy % 16, xx % 16]

    expected = (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1)) + fy * (
        (1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1)
    )
    nearest = at(np.round(y).astype(int), np.round(x).astype(int))
    assert (np.abs(x - 7.5) > 7.5).any() and (np.abs(y - 7.5) > 7.5).any()  # samples straddle the wrap
    # cv2.remap interpolates with 1/32-pixel weights: error <= 0.6 (largest step) / 64 per axis
    np.testing.assert_allclose(res.gray, expected, atol=0.02)
    assert np.abs(res.gray - nearest).max() > 0.1  # not nearest-neighbour
