"""A small self-contained rendered world for the VSE tests.

A textured height-field (a relief 0.8 x 0.6 m with bumps of a few cm) about
0.6 m in front of the camera, rendered with Open3D ray casting; the albedo is a
band-limited procedural texture of the surface position (no aliasing at the
test resolutions), with a weakly textured variant. Images are exact
(no noise) unless ``noise`` is given; the z-depth is returned too (RGB-D tests).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import exp_so3, make_pose


class SyntheticWorld:
    """Renders gray images and depth of a textured relief.

    Parameters
    ----------
    texture_contrast : float
        Amplitude of the albedo texture (0 gives a uniform, untrackable surface).
    seed : int
        Texture and relief seed.
    """

    def __init__(self, *, texture_contrast: float = 0.35, seed: int = 0, distance_m: float = 0.6):
        rng = np.random.default_rng(seed)
        nx, ny = 161, 121
        xs = np.linspace(-0.5, 0.5, nx)
        ys = np.linspace(-0.4, 0.4, ny)
        X, Y = np.meshgrid(xs, ys)
        Z = (
            distance_m
            + 0.03 * np.sin(5 * X + 1.0) * np.cos(4 * Y)
            + 0.02 * np.exp(-((X - 0.1) ** 2 + (Y + 0.05) ** 2) / 0.01)
        )
        verts = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()]).astype(np.float32)
        idx = np.arange(nx * ny).reshape(ny, nx)
        a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        tris = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])]).astype(np.uint32)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(tris))
        # band-limited texture: wavelengths 12-80 mm
        k = 40
        lam = np.exp(rng.uniform(np.log(0.012), np.log(0.08), k))
        ang = rng.uniform(0, np.pi, k)
        self._freq = (2 * np.pi / lam)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
        self._phase = rng.uniform(0, 2 * np.pi, k)
        self._amp = texture_contrast / np.sqrt(k) * np.sqrt(2)
        self.distance_m = distance_m

    def albedo(self, P: np.ndarray) -> np.ndarray:
        s = np.sin(P[:, :2] @ self._freq.T + self._phase)
        return np.clip(0.5 + self._amp * s.sum(axis=1), 0.02, 0.98)

    def render(self, camera: PinholeCamera, T_world_cam: np.ndarray, *, noise: float = 0.0, rng=None):
        """(image float32 HxW in [0, 1], depth float32 HxW in metres, 0 = miss)."""
        # Open3D puts pixel centres at +0.5; fgcd (OpenCV) at integers
        K = o3d.core.Tensor(camera.K + np.array([[0, 0, 0.5], [0, 0, 0.5], [0, 0, 0]]))
        ext = o3d.core.Tensor(np.linalg.inv(T_world_cam))
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(K, ext, camera.width, camera.height)
        ans = self.scene.cast_rays(rays)
        t = ans["t_hit"].numpy()
        r = rays.numpy()
        hit = np.isfinite(t)
        P = r[..., :3] + r[..., 3:] * np.where(hit, t, 0)[..., None]
        img = np.zeros(t.shape, np.float32)
        n = ans["primitive_normals"].numpy()
        shade = np.abs(n[..., 2])  # headlight-ish Lambert
        img[hit] = (self.albedo(P[hit].reshape(-1, 3)) * (0.3 + 0.7 * shade[hit])).astype(np.float32)
        if noise > 0:
            rng = rng or np.random.default_rng(0)
            img = np.clip(img + rng.normal(0, noise, img.shape).astype(np.float32), 0, 1)
        depth = np.where(hit, t, 0).astype(np.float32)
        return img, depth


def look_pose(center: np.ndarray, rotvec=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Camera pose in the world at ``center`` looking along +z, rotated by ``rotvec``."""
    return make_pose(exp_so3(np.asarray(rotvec, float)), np.asarray(center, float))


@pytest.fixture(scope="session")
def world() -> SyntheticWorld:
    return SyntheticWorld()


@pytest.fixture(scope="session")
def small_camera() -> PinholeCamera:
    # 320x240, 60 deg horizontal field of view
    return PinholeCamera(fx=277.0, fy=277.0, cx=159.5, cy=119.5, width=320, height=240)


def exploration_poses(n: int, *, radius_m: float = 0.03, tilt_deg: float = 3.0) -> list[np.ndarray]:
    """A slow sideways sweep with some rotation, as a robot's exploration (n frames)."""
    out = []
    for i in range(n):
        a = i / max(n - 1, 1)
        x = radius_m * np.sin(2 * np.pi * a)
        y = 0.5 * radius_m * np.sin(4 * np.pi * a)
        z = 0.01 * a
        rv = np.radians(tilt_deg) * np.array([0.5 * np.sin(2 * np.pi * a), -np.sin(2 * np.pi * a), 0.3 * a])
        out.append(look_pose([x, y, z], rv))
    return out


@pytest.fixture(scope="session")
def helpers():
    class H:
        look_pose = staticmethod(look_pose)
        exploration_poses = staticmethod(exploration_poses)
        SyntheticWorld = SyntheticWorld

    return H
