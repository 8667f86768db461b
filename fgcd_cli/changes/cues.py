"""Per-pixel change cues between the reference and a registered, light-normalized current image.

Each cue is HxW float32, larger = more likely changed, in the reference frame.
"""

from __future__ import annotations

import cv2
import numpy as np


def shift_tolerant_difference(ref_image: np.ndarray, cur_image: np.ndarray, *, radius_px: int = 1) -> np.ndarray:
    """Absolute difference, minimized over small shifts of the current image.

    The minimum over shifts of up to ``radius_px`` absorbs residual misregistration
    at edges (sub-pixel to 1 px) while a real change, larger than the shift, survives.
    Colour channels are summed (L1).

    Parameters
    ----------
    ref_image, cur_image : ndarray, HxW or HxWx3 float32 in [0, 1].
    radius_px : int
        Largest shift tried in x and y, pixels.

    Returns
    -------
    ndarray, HxW float32 (intensity units, summed over channels).
    """
    best = None
    h, w = ref_image.shape[:2]
    padded = cv2.copyMakeBorder(cur_image, radius_px, radius_px, radius_px, radius_px, cv2.BORDER_REFLECT)
    for dy in range(-radius_px, radius_px + 1):
        for dx in range(-radius_px, radius_px + 1):
            shifted = padded[radius_px + dy : radius_px + dy + h, radius_px + dx : radius_px + dx + w]
            diff = np.abs(ref_image - shifted)
            if diff.ndim == 3:
                diff = diff.sum(axis=2)
            best = diff if best is None else np.minimum(best, diff)
    return best.astype(np.float32)


def local_ncc_dissimilarity(ref_gray: np.ndarray, cur_gray: np.ndarray, *, sigma_px: float = 2.0) -> np.ndarray:
    """``1 - NCC`` in a Gaussian window: insensitive to local gain and offset.

    Returns HxW float32 in [0, 2]; flat areas (no variance) give ~0.
    """
    blur = lambda x: cv2.GaussianBlur(x, (0, 0), sigma_px)  # noqa: E731
    mean_ref, mean_cur = blur(ref_gray), blur(cur_gray)
    var_ref = blur(ref_gray * ref_gray) - mean_ref**2
    var_cur = blur(cur_gray * cur_gray) - mean_cur**2
    cov = blur(ref_gray * cur_gray) - mean_ref * mean_cur
    eps = 1e-4  # (0.01 intensity)^2: below that a window is flat and the NCC meaningless
    ncc = (cov + eps) / np.sqrt(np.maximum(var_ref + eps, 1e-12) * np.maximum(var_cur + eps, 1e-12))
    return (1.0 - ncc).astype(np.float32)


def relative_to_median(cue: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Divide a non-negative cue by its median over ``valid`` pixels (dimensionless, median 1)."""
    values = cue[valid]
    median = float(np.median(values)) if values.size else 0.0
    floor = 1e-6 if median <= 0 else 0.0
    return (np.maximum(cue, 0.0) / (median + floor + 1e-12)).astype(np.float32)
