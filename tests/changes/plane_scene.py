"""A synthetic campaign scene with exact geometry: a textured plane 1 m away, tilted 10 degrees, and a raised
block, seen from two poses; each plane is rendered by its own plane-induced homography, independently of the
code under test (tests/changes/test_geometry.py, tests/report/test_campaign_mode.py)."""

import cv2
import numpy as np
from skimage import data

W, H = 480, 360
F = 600.0
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])
# Background: a plane 1 m away, tilted 10 degrees about the vertical axis (n . X = d, reference camera frame).
N_BG = np.array([np.sin(np.deg2rad(10)), 0.0, np.cos(np.deg2rad(10))])
D_BG = 1.0
# A block whose front face is parallel to the image, 0.95 m away, over this pixel rectangle of the reference.
BLOCK = (slice(120, 240), slice(180, 300))
N_BLOCK, D_BLOCK = np.array([0.0, 0.0, 1.0]), 0.95


def texture() -> np.ndarray:
    """A real photographic texture (scikit-image 'gravel') at W x H, float32 in [0, 1]."""
    gravel = data.gravel().astype(np.float32) / 255.0
    return cv2.resize(gravel[: 2 * H, : 2 * W], (W, H), interpolation=cv2.INTER_AREA)


def plane_depth(n: np.ndarray, d: float) -> np.ndarray:
    """Z of every reference pixel on the plane n . X = d."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / F, (v - K[1, 2]) / F, np.ones_like(u)], axis=-1)
    return d / (rays @ n)


def make_pose(t_mm, rot_deg=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.deg2rad(np.asarray(rot_deg, float)))[0]
    T[:3, 3] = np.asarray(t_mm, float) * 1e-3
    return T


def homography(T_cur_ref: np.ndarray, n: np.ndarray, d: float) -> np.ndarray:
    """Reference pixel -> current pixel for points of the plane n . X = d: K (R + t n^T / d) K^-1."""
    R, t = T_cur_ref[:3, :3], T_cur_ref[:3, 3]
    return K @ (R + np.outer(t, n) / d) @ np.linalg.inv(K)


def scene(T_cur_ref: np.ndarray, *, block: bool, paint=None):
    """(reference image, current image, reference depth): each plane warped by its own homography."""
    ref = texture()
    depth = plane_depth(N_BG, D_BG)
    if block:
        depth[BLOCK] = plane_depth(N_BLOCK, D_BLOCK)[BLOCK]
    source = ref.copy()
    if paint is not None:  # a change: the surface itself differs at the visit
        cv2.circle(source, paint, 9, 0.95, -1)
    cur = cv2.warpPerspective(source, homography(T_cur_ref, N_BG, D_BG), (W, H), flags=cv2.INTER_CUBIC)
    if block:
        H_block = homography(T_cur_ref, N_BLOCK, D_BLOCK)
        mask = np.zeros((H, W), np.float32)
        mask[BLOCK] = 1.0
        seen = cv2.warpPerspective(mask, H_block, (W, H), flags=cv2.INTER_LINEAR) > 0.5
        cur[seen] = cv2.warpPerspective(source, H_block, (W, H), flags=cv2.INTER_CUBIC)[seen]
    return ref, np.clip(cur, 0.0, 1.0), depth
