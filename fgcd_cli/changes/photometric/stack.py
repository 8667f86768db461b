"""The image stack of one observation, prepared for photometric stereo (:mod:`fgcd_cli.changes.photometric.stereo`).

Directional images only (the ambient one left out), grey levels and colour per
pixel of the valid area, saturation flags, and the near-light fall-off gains.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.images import to_float_image
from fgcd_cli.errors import UserInputError

SATURATION = 0.98
"""A sample (channel) at or above this level is clipped and never fitted."""
DARK_LEVEL = 0.01
"""A pixel whose brightest directional sample is below this is unknown."""


@dataclass(kw_only=True)
class Stack:
    """The directional lightings of one observation, on its valid pixels (N of them)."""

    shape: tuple[int, int]
    index: np.ndarray  # (N,) flat indices of the valid pixels
    grey: np.ndarray  # (K', N) float32, falloff-corrected
    saturated: np.ndarray  # (K', N) bool: the grey sample is clipped
    colour: np.ndarray | None  # (3, K', N) float32, falloff-corrected; None for grey input
    channel_saturated: np.ndarray | None  # (3, K', N) bool
    used: np.ndarray  # (K,) bool


# --------------------------------------------------------------------------- input


def _falloff_gains(
    grey: np.ndarray, weight: np.ndarray, index: np.ndarray, shape: tuple[int, int], sigma_px: float
) -> np.ndarray:
    """Smooth brightness gain of each lighting relative to the mean directional image (near lights).

    Per lighting k and pixel x0, ``g_k(x0)`` is the intercept of the locally linear
    gain ``a + b . (x - x0)`` that best maps the mean directional image onto
    ``I_k`` in a Gaussian window of ``sigma_px`` (weighted least squares, pixels
    with a clipped sample left out). The ratio cancels the albedo; the linear
    term keeps a light falloff ramp unbiased up to the image border, where a
    plain ratio of blurs is not. Each gain is divided by its median, so that the
    lights keep their relative intensities. Relief finer than ~sigma survives;
    shape at larger scales is flattened towards the image-wide mean normal.

    grey (K', N) on the valid pixels ``index``; weight (H*W,) 0/1. Returns (K', N) float32.
    """
    h, w = shape
    factor = max(1, int(sigma_px / 6.0))  # the gain is smooth: work on a grid ~6 cells per sigma
    hs, ws = max(1, h // factor), max(1, w // factor)
    sigma = sigma_px * ws / w

    def down(values: np.ndarray) -> np.ndarray:
        full = np.zeros(h * w, np.float32)
        full[index] = values
        full *= weight
        return cv2.resize(full.reshape(h, w), (ws, hs), interpolation=cv2.INTER_AREA).astype(np.float64)

    def blur(image: np.ndarray) -> np.ndarray:
        return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)

    ys, xs = np.mgrid[0:hs, 0:ws].astype(np.float64)
    mean = grey.mean(axis=0)
    u = down(mean * mean)
    s0, s_x, s_y = blur(u), blur(u * xs), blur(u * ys)
    m = np.empty((hs, ws, 3, 3))
    m[..., 0, 0] = s0
    m[..., 0, 1] = m[..., 1, 0] = s_x - xs * s0
    m[..., 0, 2] = m[..., 2, 0] = s_y - ys * s0
    m[..., 1, 1] = blur(u * xs * xs) - 2 * xs * s_x + xs * xs * s0
    m[..., 2, 2] = blur(u * ys * ys) - 2 * ys * s_y + ys * ys * s0
    m[..., 1, 2] = m[..., 2, 1] = blur(u * xs * ys) - xs * s_y - ys * s_x + xs * ys * s0
    # A small ridge on the slopes: where the window holds pixels on one line only, the gain
    # falls back to the plain weighted ratio.
    support = s0 > 1e-6 * max(float(s0.max()), 1e-30)
    ridge = 0.01 * sigma * sigma * np.where(support, s0, 1.0)
    m[..., 1, 1] += ridge
    m[..., 2, 2] += ridge
    m[~support] = np.eye(3)
    gains = np.empty_like(grey)
    for k in range(grey.shape[0]):
        v = down(grey[k] * mean)
        t0 = blur(v)
        rhs = np.stack([t0, blur(v * xs) - xs * t0, blur(v * ys) - ys * t0], axis=-1)
        a = np.linalg.solve(m, rhs[..., None])[..., 0, 0]
        a = np.where(support, a, np.nan)
        fill = np.nanmedian(a) if np.isfinite(a).any() else 1.0
        a = np.where(np.isfinite(a), a, fill).astype(np.float32)
        gain = cv2.resize(a, (w, h), interpolation=cv2.INTER_LINEAR).ravel()[index]
        median = float(np.median(gain)) if gain.size else 1.0
        gains[k] = np.clip(gain / max(median, 1e-6), 0.05, 20.0)
    return gains.astype(np.float32)


def prepare_stack(images, *, valid, ambient_index, falloff_sigma_px, name) -> Stack:
    """Validate one stack and extract its directional lightings on the valid pixels."""
    if len(images) < 3:
        raise UserInputError(f"{name}: photometric stereo needs at least 3 images, got {len(images)}")
    floats = [to_float_image(im, name=f"{name} image {i + 1}") for i, im in enumerate(images)]
    shape = floats[0].shape
    for i, im in enumerate(floats):
        if im.shape != shape:
            raise UserInputError(f"{name} image {i + 1} has shape {im.shape}, image 1 has {shape}: all must match")
    h, w = shape[:2]
    used = np.ones(len(floats), bool)
    if ambient_index is not None:
        if not -len(floats) <= ambient_index < len(floats):
            raise UserInputError(f"{name}: ambient_index {ambient_index} is outside 0..{len(floats) - 1}")
        used[ambient_index] = False
    if used.sum() < 3:
        raise UserInputError(f"{name}: photometric stereo needs at least 3 directional lightings, got {used.sum()}")
    if valid is None:
        valid_mask = np.ones((h, w), bool)
    else:
        valid_mask = np.asarray(valid, bool)
        if valid_mask.shape != (h, w):
            raise UserInputError(f"{name}: valid mask is {valid_mask.shape}, images are {(h, w)}")
    directional = [floats[k] for k in np.flatnonzero(used)]
    index = np.flatnonzero(valid_mask.ravel())
    everything = index.size == h * w

    def pick(flat: np.ndarray) -> np.ndarray:
        return flat if everything else flat[index]

    colour = channel_saturated = None
    if len(shape) == 3:
        colour = np.stack([np.stack([pick(im[:, :, c].ravel()) for im in directional]) for c in range(3)])
        channel_saturated = colour >= SATURATION
        # Bright paint clips one channel under most lights: a pixel's grey is the mean of
        # its channels never clipped, the same channels in every lighting (so that the
        # pixel stays Lambertian, with the mean albedo of those channels).
        clean = ~channel_saturated.any(axis=1)  # (3, N)
        count = clean.sum(axis=0)
        some = count > 0
        share = np.where(some, clean / np.maximum(count, 1), 1.0 / 3.0).astype(np.float32)
        grey = colour[0] * share[0] + colour[1] * share[1] + colour[2] * share[2]
        saturated = channel_saturated.any(axis=0) & ~some
        clipped_anywhere = ~clean.all(axis=0)
    else:
        grey = np.stack([pick(im.ravel()) for im in directional])
        saturated = grey >= SATURATION
        clipped_anywhere = saturated.any(axis=0)

    if falloff_sigma_px:
        weight = np.zeros(h * w, np.float32)
        weight[index] = ~clipped_anywhere
        gains = _falloff_gains(grey, weight, index, (h, w), falloff_sigma_px)
        grey /= gains
        if colour is not None:
            colour /= gains[None]
    return Stack(
        shape=(h, w),
        index=index,
        grey=grey.astype(np.float32),
        saturated=saturated,
        colour=colour,
        channel_saturated=channel_saturated,
        used=used,
    )


# --------------------------------------------------------------------------- per-pixel fit
