"""Two-view geometry of the engine: triangulation, the rotation-only test and the planar motion.

Plain functions on undistorted pixels (ideal pinhole ``K``) and map-to-camera
poses ``T_cam_map`` (4x4).
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_core.camera import pinhole_pixels
from fgcd_core.se3 import invert_pose, make_pose, transform_points

__all__ = ["ray_angles_rad", "triangulate_pair", "rotation_only_residual_px", "planar_two_view"]


def ray_angles_rad(X: np.ndarray, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """Angle (radians) at each point ``X`` (N, 3) between the rays from camera centres ``c0`` and ``c1`` (3,)."""
    d0 = X - c0
    d1 = X - c1
    cosang = np.sum(d0 * d1, axis=1) / np.maximum(np.linalg.norm(d0, axis=1) * np.linalg.norm(d1, axis=1), 1e-12)
    return np.arccos(np.clip(cosang, -1, 1))


def triangulate_pair(
    K: np.ndarray, T0: np.ndarray, T1: np.ndarray, uv0: np.ndarray, uv1: np.ndarray, *, reproj_inlier_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulate undistorted pixel pairs between two map-to-camera poses.

    Parameters
    ----------
    K : (3, 3) ndarray
        Pinhole intrinsics.
    T0, T1 : (4, 4) ndarrays
        Map-to-camera poses of the two views.
    uv0, uv1 : (N, 2) ndarrays
        Undistorted pixels in each view.
    reproj_inlier_px : float
        A point is good when it lies in front of both cameras and reprojects
        within this many pixels in both.

    Returns
    -------
    X : (N, 3) ndarray
        Map points.
    good : (N,) bool ndarray
    angles : (G,) ndarray
        Ray angles (radians) of the good points.
    """
    P0 = K @ T0[:3]
    P1 = K @ T1[:3]
    Xh = cv2.triangulatePoints(P0, P1, uv0.T.astype(float), uv1.T.astype(float))
    X = (Xh[:3] / Xh[3]).T
    angles = ray_angles_rad(X, invert_pose(T0)[:3, 3], invert_pose(T1)[:3, 3])
    z0 = transform_points(T0, X)[:, 2]
    z1 = transform_points(T1, X)[:, 2]
    good = np.isfinite(X).all(axis=1) & (z0 > 0) & (z1 > 0)
    for T, uv in ((T0, uv0), (T1, uv1)):
        Xc = transform_points(T, X)
        good &= np.linalg.norm(pinhole_pixels(K, Xc) - uv, axis=1) < reproj_inlier_px
    return X, good, angles[good]


def rotation_only_residual_px(K: np.ndarray, uv0: np.ndarray, uv1: np.ndarray) -> float:
    """Median misfit (pixels) of the best pure rotation between two views' bearings.

    Solves Wahba's problem (Kabsch without translation, twice, dropping the
    worst 20 %); translation parallax is what a rotation cannot explain.

    Parameters
    ----------
    K : (3, 3) ndarray
        Pinhole intrinsics.
    uv0, uv1 : (N, 2) ndarrays
        Undistorted pixels of the same points in the two views.
    """
    Kinv = np.linalg.inv(K)
    b0 = (Kinv @ np.column_stack([uv0, np.ones(len(uv0))]).T).T
    b1 = (Kinv @ np.column_stack([uv1, np.ones(len(uv1))]).T).T
    b0 /= np.linalg.norm(b0, axis=1, keepdims=True)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    use = np.ones(len(b0), bool)
    for _ in range(2):
        U, _, Vt = np.linalg.svd(b1[use].T @ b0[use])
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
        R = U @ D @ Vt
        ang = np.arccos(np.clip(np.sum(b1 * (b0 @ R.T), axis=1), -1, 1))
        use = ang <= np.percentile(ang, 80)
    return float(np.median(ang) * K[0, 0])


def planar_two_view(
    K: np.ndarray,
    p0: np.ndarray,
    p1: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    inl: np.ndarray,
    *,
    planar_ratio: float,
    reproj_inlier_px: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two-view motion when the scene is (nearly) a plane: from the homography.

    A stele or a mural seen from 1-2 m over a few-cm baseline is a plane to
    within a fraction of a pixel of parallax; the essential matrix is then
    ill-conditioned and RANSAC can return a wrong motion (docs/vse.md, "Design and why").
    As ORB-SLAM does, the homography is preferred when it explains at least
    ``planar_ratio`` of the essential matrix's inliers. Its decomposition has up to
    two solutions with (nearly) every point in front of both cameras; of
    these the plane that faces the camera is taken, since the tool always
    looks at the surface it monitors (the other solution's normal lies
    along the translation, i.e. sideways).

    Parameters
    ----------
    K : (3, 3) ndarray
        Pinhole intrinsics.
    p0, p1 : (N, 2) ndarrays
        Undistorted pixels of the matches in the two views.
    R, t, inl : ndarrays
        The essential matrix's motion (3, 3), (3, 1) unit translation and inliers (N,).

    Returns
    -------
    (R, t, inliers), unchanged when the scene is not planar.
    """
    H, hmask = cv2.findHomography(p0, p1, cv2.RANSAC, 1.0)
    if H is None:
        return R, t, inl
    hin = hmask.ravel() > 0
    if hin.sum() < planar_ratio * inl.sum():
        return R, t, inl
    _, Rs, ts, normals = cv2.decomposeHomographyMat(H, K)
    solutions = []
    for R_i, t_i, n_i in zip(Rs, ts, normals):
        norm = float(np.linalg.norm(t_i))
        if norm < 1e-12:
            continue
        t_i = np.asarray(t_i, dtype=float).reshape(3, 1) / norm
        _, good, _ = triangulate_pair(
            K,
            np.eye(4),
            make_pose(np.asarray(R_i, float), t_i.ravel()),
            p0[hin],
            p1[hin],
            reproj_inlier_px=reproj_inlier_px,
        )
        solutions.append((int(good.sum()), abs(float(n_i[2, 0])), np.asarray(R_i, float), t_i))
    if not solutions:
        return R, t, inl
    most = max(v[0] for v in solutions)
    # points in front of both cameras (ORB-SLAM's test), then the plane facing the camera
    front = [v for v in solutions if v[0] >= 0.9 * most]
    _, _, R_h, t_h = max(front, key=lambda v: v[1])
    return R_h, t_h, hin
