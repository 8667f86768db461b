"""A lamp's light alone, from a still with the lamp on and one with it off (flash / no-flash).

Light adds: at one exposure, the linear image with a rig lamp on is the image
under the day's light plus the image under the lamp alone. The lamp rides on
the camera, so at the same pose its image is the same on every visit, whatever
the sun, the sky or the night do (docs/relocation.md, "The lamp's own image").
Linear values come from the camera's response, modelled as a power law
``linear = encoded ** gamma`` (an sRGB-like 8-bit camera: gamma 2.2; a raw
camera: 1). Hand-written: no library forms this difference with a validity rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CAMERA_RESPONSE_GAMMA", "CLIPPED_LEVEL", "LampOnlyImage", "lamp_only_image"]

#: Exponent of the camera response model ``linear = encoded ** gamma`` (sRGB-like 8-bit output).
CAMERA_RESPONSE_GAMMA = 2.2

#: An encoded value at or above this is taken as clipped (no linear value known), 8-bit: 250 of 255.
CLIPPED_LEVEL = 250.0 / 255.0

#: The lamp-only image is scaled so that this percentile of its linear values maps to 1.
_WHITE_PERCENTILE = 99.5


@dataclass(frozen=True, kw_only=True)
class LampOnlyImage:
    """The lamp's image alone and how much of the lit still it makes up.

    Attributes
    ----------
    image : (H, W) or (H, W, 3) float32 ndarray
        The lamp's light alone, encoded by the same response as the stills, in [0, 1]
        (scaled so its 99.5th percentile is 1); 0 where the lit still clipped.
    lamp_share : float
        Median over the valid pixels of the lamp's linear part over the lit still's
        linear value, in [0, 1]: 1 when the day adds nothing (a dark room, the night).
    clipped_fraction : float
        Fraction of pixels clipped in the lit still (no lamp value there).
    """

    image: np.ndarray
    lamp_share: float
    clipped_fraction: float


def lamp_only_image(lit: np.ndarray, unlit: np.ndarray, *, gamma: float = CAMERA_RESPONSE_GAMMA) -> LampOnlyImage:
    """The lamp's image alone from two stills taken at one exposure.

    Parameters
    ----------
    lit : (H, W) or (H, W, 3) ndarray, float in [0, 1]
        Still with the lamp on (the day's light and the lamp), encoded by the camera response;
        a colour still is differenced per channel, a pixel clipped in any channel is clipped.
    unlit : ndarray of ``lit``'s shape, float in [0, 1]
        Still at the same pose and the same exposure with every lamp off.
    gamma : float
        Camera response exponent (:data:`CAMERA_RESPONSE_GAMMA`).

    Returns
    -------
    LampOnlyImage

    Raises
    ------
    ValueError
        Shapes differ, or nothing of the lamp is seen (every pixel clipped or no light added).
    """
    lit = np.asarray(lit, dtype=np.float64)
    unlit = np.asarray(unlit, dtype=np.float64)
    if lit.shape != unlit.shape or lit.ndim not in (2, 3):
        raise ValueError(f"lit and unlit stills must be images of one shape, got {lit.shape} and {unlit.shape}")
    clipped = (lit >= CLIPPED_LEVEL) if lit.ndim == 2 else (lit >= CLIPPED_LEVEL).any(axis=2)
    lit_linear = np.clip(lit, 0.0, 1.0) ** gamma
    lamp = np.clip(lit_linear - np.clip(unlit, 0.0, 1.0) ** gamma, 0.0, None)
    lamp[clipped] = 0.0
    lamp_grey = lamp if lamp.ndim == 2 else lamp.mean(axis=2)
    lit_grey = lit_linear if lit_linear.ndim == 2 else lit_linear.mean(axis=2)
    valid = ~clipped & (lit_grey > 0)
    if not valid.any() or not (lamp_grey[valid] > 0).any():
        raise ValueError("the lamp adds no light to the still (every pixel clipped or unchanged)")
    white = float(np.percentile(lamp[valid], _WHITE_PERCENTILE))
    if white <= 0:
        raise ValueError("the lamp adds no light to most of the still")
    share = float(np.median(lamp_grey[valid] / lit_grey[valid]))
    image = (np.clip(lamp / white, 0.0, 1.0) ** (1.0 / gamma)).astype(np.float32)
    return LampOnlyImage(image=image, lamp_share=min(max(share, 0.0), 1.0), clipped_fraction=float(clipped.mean()))
