"""Albedo textures: the real photographs bundled with scikit-image plus procedural detail.

All textures are (H, W, 3) float32 albedo in [0, 1]. Nothing is downloaded: the
scikit-image images used here ship inside the package.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

__all__ = ["PHOTOS", "photo", "fractal_noise", "tinted", "stone", "blend_detail"]

#: skimage.data images that ship with the package (no download).
PHOTOS = (
    "astronaut",
    "brick",
    "camera",
    "coffee",
    "gravel",
    "grass",
    "moon",
    "rocket",
    "text",
    "chelsea",
    "coins",
    "page",
    "clock",
    "hubble_deep_field",
    "immunohistochemistry",
    "retina",
)


@lru_cache(maxsize=32)
def _photo_cached(name: str) -> np.ndarray:
    import skimage.data

    if name not in PHOTOS:
        raise ValueError(f"unknown texture photo {name!r}; known: {', '.join(PHOTOS)}")
    img = np.asarray(getattr(skimage.data, name)())
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    img = img.astype(np.float32) / (65535.0 if img.dtype == np.uint16 else 255.0)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    img = img[:, :, :3]
    img.setflags(write=False)
    return img


def photo(name: str, *, size: tuple[int, int] | None = None) -> np.ndarray:
    """A bundled photograph as (H, W, 3) float32 in [0, 1], optionally resized to ``(h, w)``."""
    img = _photo_cached(name)
    if size is not None and img.shape[:2] != tuple(size):
        img = cv2.resize(img, (int(size[1]), int(size[0])), interpolation=cv2.INTER_CUBIC)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


def fractal_noise(
    shape: tuple[int, int],
    rng: np.random.Generator,
    *,
    octaves: int = 5,
    base_sigma: float = 32.0,
    persistence: float = 0.55,
    wrap: bool = True,
) -> np.ndarray:
    """Zero-mean, unit-std multi-scale noise (sum of Gaussian-blurred white noise).

    ``wrap`` makes it tile seamlessly (blur with wrapped borders).
    """
    h, w = shape
    out = np.zeros((h, w), np.float32)
    amp = 1.0
    sigma = float(base_sigma)
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.rfftfreq(w)[None, :]
    f2 = (fx**2 + fy**2).astype(np.float32)
    for _ in range(octaves):
        n = rng.standard_normal((h, w)).astype(np.float32)
        if sigma >= 0.6:
            if wrap:
                # periodic blur through the FFT (OpenCV's GaussianBlur has no wrap-around border)
                gain = np.exp(-2.0 * (np.pi * sigma) ** 2 * f2)
                n = np.fft.irfft2(np.fft.rfft2(n) * gain, s=(h, w)).astype(np.float32)
            else:
                k = int(2 * round(3 * sigma) + 1)
                n = cv2.GaussianBlur(n, (k, k), sigma, borderType=cv2.BORDER_REFLECT)
        n /= n.std() + 1e-12
        out += amp * n
        amp *= persistence
        sigma /= 2.0
    out -= out.mean()
    out /= out.std() + 1e-12
    return out


def tinted(gray: np.ndarray, colour) -> np.ndarray:
    """Multiply a gray (H, W) or (H, W, 3) image by an RGB colour."""
    g = gray if gray.ndim == 2 else gray.mean(axis=2)
    return np.clip(g[:, :, None] * np.asarray(colour, np.float32)[None, None, :], 0, 1).astype(np.float32)


def blend_detail(
    base: np.ndarray, rng: np.random.Generator, *, amount: float = 0.08, base_sigma: float = 4.0
) -> np.ndarray:
    """Add fine procedural grain (multiplicative) so close-ups keep texture."""
    n = fractal_noise(base.shape[:2], rng, octaves=3, base_sigma=base_sigma)
    return np.clip(base * (1.0 + amount * n[:, :, None]), 0, 1).astype(np.float32)


def stone(
    rng: np.random.Generator,
    *,
    size: int = 1024,
    photo_name: str = "gravel",
    colour=(0.72, 0.64, 0.52),
    contrast: float = 0.6,
    detail: float = 0.10,
) -> np.ndarray:
    """Stone albedo: a tinted bundled photo, large-scale mottling and fine grain."""
    base = photo(photo_name, size=(size, size)).mean(axis=2)
    base = 0.5 + contrast * (base - base.mean())
    mottle = fractal_noise((size, size), rng, octaves=4, base_sigma=size / 8)
    g = np.clip(base * (1.0 + 0.12 * mottle), 0.05, 1.0)
    return blend_detail(tinted(g, np.asarray(colour) * 1.25), rng, amount=detail)
