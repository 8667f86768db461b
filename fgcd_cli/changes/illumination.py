"""Illumination normalization between a registered current image and the reference."""

from __future__ import annotations

import cv2
import numpy as np


def smooth_large(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur of scale ``sigma_px``, computed on a reduced grid when the scale is large.

    For sigma >= 24 px the image is area-averaged by ``f = floor(sigma / 3)`` (a box
    of variance f^2/12, subtracted from the Gaussian's), blurred there and resized
    back bilinearly: ~8x faster than the full kernel, with errors of a few percent
    of the image's contrast where it has sharp edges (the box aliases them), so it
    is for the wide fallback window of the gain, not for the gain itself. Smaller
    scales use the exact kernel.

    Parameters
    ----------
    image : ndarray, HxW or HxWxC float32
    sigma_px : float, Gaussian scale in pixels of ``image``

    Returns
    -------
    ndarray, float32, the shape of ``image``
    """
    factor = int(sigma_px // 3)
    h, w = image.shape[:2]
    if factor < 8 or min(h, w) < 8 * factor:
        return cv2.GaussianBlur(image, (0, 0), sigma_px)
    small = cv2.resize(image, (int(np.ceil(w / factor)), int(np.ceil(h / factor))), interpolation=cv2.INTER_AREA)
    sigma_small = np.sqrt(max(sigma_px**2 - factor**2 / 12.0, 1e-6)) / factor
    small = cv2.GaussianBlur(small, (0, 0), sigma_small, borderType=cv2.BORDER_REFLECT)
    # Map output pixel centres onto the reduced grid (pixel-centre convention of INTER_AREA).
    xs = ((np.arange(w, dtype=np.float32) + 0.5) / factor - 0.5)
    ys = ((np.arange(h, dtype=np.float32) + 0.5) / factor - 0.5)
    map_x = np.broadcast_to(xs[None, :], (h, w)).astype(np.float32)
    map_y = np.broadcast_to(ys[:, None], (h, w)).astype(np.float32)
    out = cv2.remap(small, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(image.shape).astype(np.float32)


def normalize_local_gain(
    ref_image: np.ndarray,
    cur_warped: np.ndarray,
    *,
    sigma_px: float = 12.0,
    floor: float = 0.01,
    weight: np.ndarray | None = None,
) -> np.ndarray:
    """Correct a smooth, spatially varying light gain on the current image.

    The gain ``G = mean_ref / mean_cur`` (local Gaussian means, per channel)
    absorbs light falloff, exposure and white-balance differences whose scale is
    larger than ``sigma_px``; changes smaller than that survive.

    A change inside the window biases the local means: a dark spot of a few
    hundred pixels lowers ``mean_cur`` and brightens its unchanged surroundings
    by 20-50 %, a halo as wide as the window. ``weight`` (0 on pixels suspected
    of change) makes the means weighted (normalized convolution), so the gain
    there is interpolated from the unchanged surroundings.

    Parameters
    ----------
    ref_image, cur_warped : ndarray, HxW or HxWx3 float32 in [0, 1], same frame.
    sigma_px : float
        Gaussian scale of the gain field, pixels.
    floor : float
        Added to both means so dark areas do not explode the gain.
    weight : ndarray, HxW float in [0, 1], optional
        Trust of each pixel for the gain estimate (None: all pixels count).
        Where the weighted window holds almost no trusted pixel, a 4x wider
        window is used.

    Returns
    -------
    ndarray, the current image with the gain applied (float32, same shape).
    """
    blur = smooth_large
    if weight is None:
        gain = (blur(ref_image, sigma_px) + floor) / (blur(cur_warped, sigma_px) + floor)
        return (cur_warped * gain).astype(np.float32)
    w = np.asarray(weight, dtype=np.float32)
    w3 = w[:, :, None] if ref_image.ndim == 3 else w

    def weighted_gain(s: float) -> tuple[np.ndarray, np.ndarray]:
        wb = blur(w, s)
        wb3 = wb[:, :, None] if ref_image.ndim == 3 else wb
        denom = np.maximum(wb3, 1e-6)
        g = (blur(w3 * ref_image, s) / denom + floor) / (blur(w3 * cur_warped, s) / denom + floor)
        return g, wb3

    gain, support = weighted_gain(sigma_px)
    if float(support.min()) < 0.05:
        wide, _ = weighted_gain(4.0 * sigma_px)
        # Blend smoothly towards the wide estimate where the narrow window has little support.
        alpha = np.clip(support / 0.05, 0.0, 1.0)
        gain = alpha * gain + (1.0 - alpha) * wide
    return (cur_warped * gain).astype(np.float32)


def shading_from_normals(normals_cam: np.ndarray, light_dir_cam: np.ndarray) -> np.ndarray:
    """Lambertian shading ``max(0, n·l)`` for per-pixel normals and one light direction.

    Parameters
    ----------
    normals_cam : ndarray, HxWx3 float, unit normals in the camera frame (NaN where unknown).
    light_dir_cam : ndarray, 3, direction towards the light in the camera frame.

    Returns
    -------
    ndarray, HxW float32 in [0, 1] (0 where the normal is unknown).
    """
    light = np.asarray(light_dir_cam, dtype=np.float64)
    light = light / np.linalg.norm(light)
    shading = np.einsum("hwc,c->hw", np.nan_to_num(normals_cam.astype(np.float64)), light)
    return np.clip(shading, 0.0, 1.0).astype(np.float32)


def normalize_shading(
    ref_image: np.ndarray,
    cur_warped: np.ndarray,
    *,
    shading_ref: np.ndarray,
    shading_cur: np.ndarray,
    min_shading: float = 0.05,
) -> np.ndarray:
    """Re-light the current image to the reference's lighting with known shading maps.

    With per-pixel normals (from the observation's 3D points) and the capture's
    light direction, albedo ``= image / shading``; the current image is divided by
    its own shading and multiplied by the reference's, so only albedo or geometry
    changes remain. Pixels with shading below ``min_shading`` keep their value.

    Parameters
    ----------
    ref_image, cur_warped : ndarray, HxW or HxWx3 float32, reference frame.
    shading_ref, shading_cur : ndarray, HxW float32, shading of each capture in the reference frame.
    """
    ratio = np.where(
        (shading_cur > min_shading) & (shading_ref > min_shading),
        shading_ref / np.maximum(shading_cur, min_shading),
        1.0,
    ).astype(np.float32)
    if cur_warped.ndim == 3:
        ratio = ratio[:, :, None]
    return np.clip(cur_warped * ratio, 0.0, 1.0).astype(np.float32)
