"""The simulated sensor's response: exposure, vignetting, read and shot noise, gamma, quantisation, compression.

Applied by :class:`fgcd_drivers.sim.render.Renderer` after shading (linear radiance
in, image in [0, 1] out).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["CameraEffects", "apply_camera_response", "auto_exposure", "LUMA"]

#: Rec. 601 luma weights: grey = LUMA . (R, G, B) on linear radiance.
LUMA = np.array([0.299, 0.587, 0.114], np.float32)


@dataclass(frozen=True, kw_only=True)
class CameraEffects:
    """Sensor and lens effects applied after shading.

    Attributes
    ----------
    gamma : float
        Display gamma (output = linear ** (1/gamma)); 1 keeps the image linear.
    vignetting : float
        Relative fall-off at the image corner (0 = none; 0.3 = corners 30 % darker).
    read_noise : float
        Std of additive noise in linear output units.
    shot_noise : float
        Std of signal-dependent noise: sigma^2 = read^2 + shot^2 * value.
    max_exposure : float
        Largest exposure (gain) auto-exposure may use.
    bit_depth : int or None
        Bits per sample of the camera's output (8: an 8-bit frame, 12: a raw one); None keeps floats.
    jpeg_quality : int or None
        Where the camera compresses its frames (JPEG quality 1-100, on the 8-bit image); None: no
        compression (the FGCD photographs and the rig's frames are lossless).
    """

    gamma: float = 2.2
    vignetting: float = 0.0
    read_noise: float = 0.0
    shot_noise: float = 0.0
    max_exposure: float = 64.0
    bit_depth: int | None = None
    jpeg_quality: int | None = None


def auto_exposure(
    linear_gray: np.ndarray, valid: np.ndarray | None = None, *, target: float = 0.18, max_exposure: float = 64.0
) -> float:
    """Exposure that maps the median lit value to ``target`` without clipping most highlights."""
    v = linear_gray[valid] if valid is not None and valid.any() else linear_gray.ravel()
    if v.size == 0:
        return 1.0
    p50 = float(np.percentile(v, 50))
    p99 = float(np.percentile(v, 99.5))
    e = target / max(p50, 1e-6)
    e = min(e, 0.9 / max(p99, 1e-6))
    return float(min(max(e, 1e-3), max_exposure))


def apply_camera_response(
    linear: np.ndarray, *, exposure: float, effects: CameraEffects, rng: np.random.Generator | None = None
) -> np.ndarray:
    """Exposure, vignetting, noise and gamma: linear radiance -> image in [0, 1] (float32)."""
    v = linear.astype(np.float32) * np.float32(exposure)
    h, w = v.shape[:2]
    if effects.vignetting > 0:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
        vig = 1.0 - effects.vignetting * r2
        v = v * (vig[..., None] if v.ndim == 3 else vig)
    if (effects.read_noise > 0 or effects.shot_noise > 0) and rng is not None:
        sigma = np.sqrt(effects.read_noise**2 + effects.shot_noise**2 * np.maximum(v, 0))
        v = v + sigma * rng.standard_normal(v.shape, dtype=np.float32)
    v = np.clip(v, 0.0, 1.0)
    if effects.gamma != 1.0:
        v = v ** np.float32(1.0 / effects.gamma)
    if effects.jpeg_quality is not None:
        v = _jpeg_round_trip(v, effects.jpeg_quality)
    elif effects.bit_depth is not None:
        levels = np.float32(2**effects.bit_depth - 1)
        v = np.round(v * levels) / levels
    return v.astype(np.float32)


def _jpeg_round_trip(image: np.ndarray, quality: int) -> np.ndarray:
    """The image as an 8-bit JPEG of ``quality`` decodes it (OpenCV's codec), in [0, 1]."""
    u8 = np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)
    colour = u8.ndim == 3
    ok, buf = cv2.imencode(".jpg", u8[..., ::-1] if colour else u8, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("the JPEG encoder refused the frame")
    out = cv2.imdecode(buf, cv2.IMREAD_COLOR if colour else cv2.IMREAD_GRAYSCALE)
    return (out[..., ::-1] if colour else out).astype(np.float32) / np.float32(255.0)
