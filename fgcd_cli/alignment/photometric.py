"""Image side of the photometric term: blurred images with gradients, bilinear
sampling, projection Jacobians and per-keyframe occlusion (z-buffer) tests.
"""

from __future__ import annotations

import cv2
import numpy as np

from fgcd_core.camera import PinholeCamera
from fgcd_core.imaging import to_gray_f32

__all__ = ["KeyframeImage", "prepare_keyframe", "sample", "project_with_jacobian", "visible_nearest"]


class KeyframeImage:
    """A keyframe image blurred for one pyramid level, with its gradients stacked.

    Attributes
    ----------
    stack : (H, W, 3) float32 ndarray
        Intensity, d/du and d/dv (grey levels per pixel).
    """

    def __init__(self, stack: np.ndarray) -> None:
        self.stack = stack
        self.height, self.width = stack.shape[:2]


def prepare_keyframe(image: np.ndarray, *, blur_sigma: float) -> KeyframeImage:
    """Blur a grey image (uint8, or float in [0, 1]; RGB is converted) and compute its gradients.

    Grey levels in [0, 1] by :func:`fgcd_core.imaging.to_gray_f32` (Rec. 601 luma for RGB).
    The gradient is the central difference (``cv2.Sobel`` with ``ksize=1`` halved),
    consistent with bilinear sampling of the blurred image.
    """
    img = to_gray_f32(image)
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    gu = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=1) * 0.5
    gv = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=1) * 0.5
    return KeyframeImage(np.dstack([img, gu, gv]))


def sample(kf: KeyframeImage, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of intensity and gradient at (N, 2) pixel positions.

    Returns
    -------
    values : (N, 3) ndarray
        ``(I, dI/du, dI/dv)``.
    inside : (N,) bool ndarray
        At least one pixel away from the border (where the bilinear sample is valid).
    """
    u = uv[:, 0].astype(np.float32)
    v = uv[:, 1].astype(np.float32)
    inside = (uv[:, 0] >= 1) & (uv[:, 0] <= kf.width - 2) & (uv[:, 1] >= 1) & (uv[:, 1] <= kf.height - 2)
    # cv2.remap needs map sides below 32767: lay the samples out as a (rows, 4096) map.
    n = len(u)
    cols = 4096
    rows = max(1, -(-n // cols))
    pad = rows * cols - n
    mu = np.pad(u, (0, pad)).reshape(rows, cols)
    mv = np.pad(v, (0, pad)).reshape(rows, cols)
    out = cv2.remap(kf.stack, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n].astype(float), inside


def project_with_jacobian(camera: PinholeCamera, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pinhole projection (no distortion) and its Jacobian.

    Parameters
    ----------
    X : (N, 3) ndarray
        Camera-frame points.

    Returns
    -------
    uv : (N, 2) ndarray
    duv_dX : (N, 2, 3) ndarray
    front : (N,) bool ndarray
        ``Z`` above 1 mm.
    """
    Z = X[:, 2]
    front = Z > 1e-3
    iz = 1.0 / np.where(front, Z, 1.0)
    x = X[:, 0] * iz
    y = X[:, 1] * iz
    uv = np.column_stack([camera.fx * x + camera.cx, camera.fy * y + camera.cy])
    J = np.zeros((len(X), 2, 3))
    J[:, 0, 0] = camera.fx * iz
    J[:, 0, 2] = -camera.fx * x * iz
    J[:, 1, 1] = camera.fy * iz
    J[:, 1, 2] = -camera.fy * y * iz
    return uv, J, front


def visible_nearest(
    uv: np.ndarray, depth: np.ndarray, valid: np.ndarray, *, width: int, height: int, cell_px: int, depth_tol: float
) -> np.ndarray:
    """Occlusion test: keep only points near the nearest depth of their image cell.

    The paper keeps, among reference points projecting to the same pixel, only
    the one nearest to the camera. The reference cloud is about as dense as the
    pixels, so an occluded point often has no occluder in its own pixel; cells of
    ``cell_px`` pixels with a relative depth tolerance make the test effective.

    Parameters
    ----------
    uv : (N, 2) ndarray
    depth : (N,) ndarray
        Camera z-depth, metres.
    valid : (N,) bool ndarray
        In front of the camera and inside the image.

    Returns
    -------
    visible : (N,) bool ndarray
    """
    visible = np.zeros(len(uv), dtype=bool)
    idx = np.flatnonzero(valid)
    if len(idx) == 0:
        return visible
    cu = np.clip((uv[idx, 0] // cell_px).astype(np.int64), 0, width // cell_px + 1)
    cv = np.clip((uv[idx, 1] // cell_px).astype(np.int64), 0, height // cell_px + 1)
    cell = cv * (width // cell_px + 2) + cu
    zmin = np.full(int(cell.max()) + 1, np.inf)
    np.minimum.at(zmin, cell, depth[idx])
    visible[idx] = depth[idx] <= zmin[cell] * (1.0 + depth_tol)
    return visible
