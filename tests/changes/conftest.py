"""Synthetic scenes with known change and motion, shared by the change-detection tests."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data


def textured_scene(size: int = 256) -> np.ndarray:
    """A real photographic texture (scikit-image 'gravel'), float32 in [0, 1], size x size."""
    gravel = data.gravel().astype(np.float32) / 255.0
    return cv2.resize(gravel[: size * 2, : size * 2], (size, size), interpolation=cv2.INTER_AREA)


def translate(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """Content moves by (dx, dy) pixels: out(x) = in(x - d)."""
    M = np.float32([[1, 0, dx], [0, 1, dy]])
    moved = cv2.warpAffine(
        image, M, (image.shape[1], image.shape[0]), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )
    return np.clip(moved, 0.0, 1.0)


@pytest.fixture
def scene_pair():
    """Reference, current (moved 2.3, -1.6 px, gain ramp 0.75..1.25, one changed disc) and the change truth."""
    ref = textured_scene()
    h, w = ref.shape
    truth = np.zeros((h, w), bool)
    cv2.circle(truth.view(np.uint8), (170, 90), 12, 1, -1)
    changed = ref.copy()
    # A flake of paint lost: the disc shows a brighter, flat plaster underneath.
    changed[truth] = 0.85
    dx, dy = 2.3, -1.6
    cur = translate(changed, dx, dy)
    gain = np.linspace(0.75, 1.25, w, dtype=np.float32)[None, :]
    cur = np.clip(cur * gain, 0, 1)
    return {"ref": ref, "cur": cur, "truth": truth, "shift": (dx, dy)}
