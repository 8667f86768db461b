"""Synthetic scenes with known geometry for tests and the alignment benchmark.

A relief (smooth random height field with a smooth random albedo, like a carved
stele seen from the front), a plane and a sphere, sampled as point clouds and
rendered as grey images with Open3D's ``RaycastingScene``. Nothing here is used
by the alignment algorithms themselves; ground truth is explicit in every return.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from fgcd_cli.geometry import PinholeCamera, Sim3, exp_se3, invert_pose, make_pose

__all__ = [
    "ReliefScene",
    "sample_plane",
    "sample_sphere",
    "random_similarity",
    "look_at",
]


@dataclass(kw_only=True)
class ReliefScene:
    """Height field ``z = h(x, y)`` over ``[-width/2, width/2]^2`` with an albedo texture.

    Cameras look along ``+z`` from ``z < 0`` (see :func:`look_at`); the relief
    rises towards them (negative z).

    Parameters
    ----------
    seed : int
        Fixes bumps and texture.
    width : float
        Side of the square support, metres.
    amplitude : float
        Typical bump height, metres.
    """

    seed: int = 0
    width: float = 0.5
    amplitude: float = 0.03
    n_bumps: int = 40
    texture_texels: int = 1024
    _bumps: np.ndarray = field(init=False, repr=False)
    _texture: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        half = self.width / 2
        centres = rng.uniform(-half, half, size=(self.n_bumps, 2))
        sigmas = rng.uniform(0.04, 0.12, size=self.n_bumps) * self.width
        heights = rng.normal(0.0, self.amplitude, size=self.n_bumps)
        self._bumps = np.column_stack([centres, sigmas, heights])
        noise = rng.random((self.texture_texels, self.texture_texels))
        tex = sum(gaussian_filter(noise, s, mode="wrap") * w for s, w in ((6, 1.0), (14, 1.5), (30, 2.0)))
        tex = (tex - tex.mean()) / (tex.std() + 1e-12)
        self._texture = np.clip(0.5 + 0.18 * tex, 0.02, 0.98)

    def height(self, xy: np.ndarray) -> np.ndarray:
        """Surface z (m) at (N, 2) positions; the relief protrudes towards -z."""
        xy = np.asarray(xy, dtype=float)
        z = np.zeros(len(xy))
        for cx, cy, s, h in self._bumps:
            z -= h * np.exp(-((xy[:, 0] - cx) ** 2 + (xy[:, 1] - cy) ** 2) / (2 * s * s))
        return z

    def albedo(self, xy: np.ndarray) -> np.ndarray:
        """Grey albedo in [0, 1] at (N, 2) positions (bilinear in the texture)."""
        xy = np.asarray(xy, dtype=float)
        n = self.texture_texels
        uv = (xy / self.width + 0.5) * (n - 1)
        return map_coordinates(self._texture, [uv[:, 1], uv[:, 0]], order=1, mode="nearest")

    def sample(
        self, n: int, *, rng: np.random.Generator, xlim=None, ylim=None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Uniform surface samples in the (x, y) window.

        Returns
        -------
        points : (n, 3), normals : (n, 3), intensities : (n,)
        """
        half = self.width / 2
        xlim = (-half, half) if xlim is None else xlim
        ylim = (-half, half) if ylim is None else ylim
        xy = np.column_stack([rng.uniform(*xlim, size=n), rng.uniform(*ylim, size=n)])
        pts = np.column_stack([xy, self.height(xy)])
        eps = 1e-4
        dzdx = (self.height(xy + [eps, 0]) - self.height(xy - [eps, 0])) / (2 * eps)
        dzdy = (self.height(xy + [0, eps]) - self.height(xy - [0, eps])) / (2 * eps)
        normals = np.column_stack([dzdx, dzdy, -np.ones(n)])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        return pts, normals, self.albedo(xy)

    def mesh(self, resolution: int = 160) -> tuple[np.ndarray, np.ndarray]:
        """Triangle mesh of the height field: vertices (V, 3) float32, triangles (F, 3) uint32."""
        half = self.width / 2
        g = np.linspace(-half, half, resolution)
        X, Y = np.meshgrid(g, g)
        xy = np.column_stack([X.ravel(), Y.ravel()])
        V = np.column_stack([xy, self.height(xy)]).astype(np.float32)
        i, j = np.meshgrid(np.arange(resolution - 1), np.arange(resolution - 1), indexing="ij")
        a = (i * resolution + j).ravel()
        b, c, d = a + 1, a + resolution, a + resolution + 1
        F = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])]).astype(np.uint32)
        return V, F

    def render(
        self, camera: PinholeCamera, T_ref_cam: np.ndarray, *, light_dir=(0.3, -0.4, 1.0)
    ) -> tuple[np.ndarray, np.ndarray]:
        """Grey image (float32 in [0, 1]) and z-depth (m, 0 = background) seen by a camera.

        Lambertian shading with one directional light plus ambient; albedo
        sampled bilinearly at the exact ray hit (no texel aliasing).
        """
        import open3d as o3d

        if not hasattr(self, "_scene"):
            V, F = self.mesh()
            self._scene = o3d.t.geometry.RaycastingScene()
            self._scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(F))
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            o3d.core.Tensor(camera.K),
            o3d.core.Tensor(invert_pose(T_ref_cam)),
            camera.width,
            camera.height,
        )
        hit = self._scene.cast_rays(rays)
        t_hit = hit["t_hit"].numpy()
        ok = np.isfinite(t_hit)
        r = rays.numpy()
        P = r[..., :3] + r[..., 3:] * np.where(ok, t_hit, 0)[..., None]
        normal = hit["primitive_normals"].numpy()
        normal = np.where((normal[..., 2] > 0)[..., None], -normal, normal)
        light = np.asarray(light_dir, dtype=float)
        light = -light / np.linalg.norm(light)
        shade = 0.35 + 0.65 * np.clip(normal @ light, 0.0, 1.0)
        img = np.zeros(t_hit.shape, dtype=np.float32)
        img[ok] = (self.albedo(P[ok][:, :2]) * shade[ok]).astype(np.float32)
        # z-depth: the rays from create_rays_pinhole have unit camera-z component.
        depth = np.where(ok, t_hit, 0.0)
        return img, depth


def sample_plane(n: int, *, rng: np.random.Generator, width: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) and normals on the square ``z = 0``, side ``width``."""
    half = width / 2
    pts = np.column_stack([rng.uniform(-half, half, size=(n, 2)), np.zeros(n)])
    return pts, np.tile([0.0, 0.0, -1.0], (n, 1))


def sample_sphere(n: int, *, rng: np.random.Generator, radius: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) and outward normals uniformly on a sphere about the origin."""
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return radius * v, v


def random_similarity(
    rng: np.random.Generator, *, rotation_deg: float, translation_m: float, scale_rel: float
) -> Sim3:
    """A similarity with rotation angle, translation norm and ``|scale - 1|`` of the given sizes (random axes/signs)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    T = exp_se3(np.concatenate([translation_m * direction, np.radians(rotation_deg) * axis]))
    sign = 1.0 if rng.random() < 0.5 else -1.0
    return Sim3(T[:3, :3], T[:3, 3], 1.0 + sign * scale_rel)


def look_at(eye: np.ndarray, target: np.ndarray, *, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """Camera pose ``T_world_cam`` (OpenCV axes: z forward, y down) at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.column_stack([x, y, z]), eye)
