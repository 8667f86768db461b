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

from fgcd_core import se3
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import exp_se3, invert_pose
from fgcd_core.sim3 import Sim3

__all__ = [
    "ReliefScene",
    "sample_plane",
    "sample_sphere",
    "random_similarity",
    "SCENE_UP",
    "look_at",
    "SyntheticSession",
    "SessionConfig",
    "make_session",
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


def random_similarity(rng: np.random.Generator, *, rotation_deg: float, translation_m: float, scale_rel: float) -> Sim3:
    """A similarity with rotation angle, translation norm and ``|scale - 1|`` of the given sizes (random axes/signs)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    T = exp_se3(np.concatenate([translation_m * direction, np.radians(rotation_deg) * axis]))
    sign = 1.0 if rng.random() < 0.5 else -1.0
    return Sim3(T[:3, :3], T[:3, 3], 1.0 + sign * scale_rel)


#: World direction that appears upwards in images of the synthetic scenes.
SCENE_UP = (0.0, -1.0, 0.0)


def look_at(eye: np.ndarray, target: np.ndarray, *, up=SCENE_UP) -> np.ndarray:
    """Camera pose ``T_world_cam`` (OpenCV axes: z forward, y down) at ``eye`` looking at ``target``.

    :func:`fgcd_core.se3.look_at` with the synthetic scenes' ``up`` (``-y``); a view along
    ``up`` uses ``+z`` instead.
    """
    return se3.look_at(eye, target, up=up, fallback_up=(0.0, 0.0, 1.0))


@dataclass(kw_only=True)
class SyntheticSession:
    """A current session over a :class:`ReliefScene` as a VSE would deliver it, with ground truth.

    Attributes
    ----------
    keyframes : list of (T_cur_cam (4, 4), image (H, W) float32)
        Keyframe poses in the current map frame *with* VSE-like pose errors, and
        images rendered from the true poses.
    cur_points : (N, 3) ndarray
        Semi-dense current cloud (high-gradient pixels), depth noise, built with
        the erroneous keyframe poses; map frame.
    keyframe_ids : (N,) int ndarray
    T_ref_cur : Sim3
        True map -> reference similarity.
    T_ref_cam_true : list of (4, 4) ndarray
        True keyframe poses in the reference frame.
    """

    keyframes: list
    cur_points: np.ndarray
    keyframe_ids: np.ndarray
    T_ref_cur: Sim3
    T_ref_cam_true: list


@dataclass(frozen=True, kw_only=True)
class SessionConfig:
    """Options of :func:`make_session`.

    Camera centres lie on a circle (radius ``baseline``) at ``distance`` in front of
    ``centre``, all looking at it. Pose errors are independent per keyframe
    (rotation ``pose_noise_deg``, translation ``pose_noise_m`` per axis, Gaussian);
    depth noise is relative (``depth_noise_rel`` of the depth).
    """

    n_keyframes: int = 6
    distance: float = 0.6
    """Metres."""
    baseline: float = 0.08
    """Metres."""
    pose_noise_deg: float = 0.15
    pose_noise_m: float = 0.0015
    depth_noise_rel: float = 0.003
    points_per_keyframe: int = 4000
    centre: tuple[float, float] = (0.0, 0.0)
    """(x, y) of the viewed point on the relief, metres."""


def make_session(
    scene: ReliefScene,
    *,
    camera: PinholeCamera,
    T_ref_cur: Sim3,
    rng: np.random.Generator,
    config: SessionConfig | None = None,
) -> SyntheticSession:
    """Render keyframes around a frontal view of the relief and build the current cloud.

    Parameters
    ----------
    scene : ReliefScene
    camera : PinholeCamera
    T_ref_cur : Sim3
        True map -> reference similarity.
    rng : numpy.random.Generator
        Pose errors, depth noise and pixel choice.
    config : SessionConfig, optional
        The session's geometry and noise (default: :class:`SessionConfig`).
    """
    cfg = config or SessionConfig()
    centre = cfg.centre
    target = np.array([centre[0], centre[1], 0.0])
    kfs, truths, pts, ids = [], [], [], []
    for k in range(cfg.n_keyframes):
        ang = 2 * np.pi * k / cfg.n_keyframes
        eye = target + np.array([cfg.baseline * np.cos(ang), cfg.baseline * np.sin(ang), -cfg.distance])
        T_ref_cam = look_at(eye, target)
        img, depth = scene.render(camera, T_ref_cam)
        T_cur_cam_true = T_ref_cur.inverse().transform_pose(T_ref_cam)
        noise = exp_se3(
            np.concatenate(
                [rng.normal(0, cfg.pose_noise_m, 3) / T_ref_cur.scale, np.radians(rng.normal(0, cfg.pose_noise_deg, 3))]
            )
        )
        T_cur_cam = T_cur_cam_true @ noise
        # Semi-dense: pixels with strong gradient, as a direct VSE keeps them.
        gy, gx = np.gradient(img.astype(float))
        g = np.hypot(gx, gy)
        valid = depth > 0
        cand = np.flatnonzero(valid.ravel() & (g.ravel() > np.percentile(g[valid], 60)))
        pick = rng.choice(cand, min(cfg.points_per_keyframe, len(cand)), replace=False)
        v, u = np.unravel_index(pick, depth.shape)
        z = depth[v, u] * (1.0 + rng.normal(0, cfg.depth_noise_rel, len(pick)))
        X = camera.unproject(np.column_stack([u, v]).astype(float), z)
        pts.append((X / T_ref_cur.scale) @ T_cur_cam[:3, :3].T + T_cur_cam[:3, 3])
        ids.append(np.full(len(pick), k))
        kfs.append((T_cur_cam, img))
        truths.append(T_ref_cam)
    return SyntheticSession(
        keyframes=kfs,
        cur_points=np.concatenate(pts),
        keyframe_ids=np.concatenate(ids),
        T_ref_cur=T_ref_cur,
        T_ref_cam_true=truths,
    )
