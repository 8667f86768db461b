"""The KLT front-end's corner detector: the absolute response is the threshold, whatever else is in view."""

import cv2
import numpy as np

from fgcd_cli.vse.features import KltFrontend


def _soft_texture(*, seed: int = 0, shape=(240, 320)) -> np.ndarray:
    """A low-contrast texture (a mural under a torch): blobs of a few pixels, +-6 grey levels, plus 1 level of noise."""
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.normal(0.0, 1.0, shape), (0, 0), 2.0)
    base *= 6.0 / base.std()
    return np.clip(120.0 + base + rng.normal(0.0, 1.0, shape), 0, 255).astype(np.uint8)


def test_one_strong_dark_spot_does_not_hide_the_texture():
    klt = KltFrontend(min_corner_response=2e-4)
    img = _soft_texture()
    alone = klt.detect(img, np.zeros((0, 2)), 200)
    # a black pit 6 px across: its response is ~100x the texture's, so a threshold relative to the
    # strongest corner (OpenCV's qualityLevel = 0.01) would keep almost nothing else
    spotted = img.copy()
    cv2.circle(spotted, (160, 120), 3, 0, -1)
    e = cv2.cornerMinEigenVal(spotted, 7, 3)
    texture_only = np.percentile(cv2.cornerMinEigenVal(img, 7, 3), 99)
    assert e.max() > 50 * texture_only  # the case: one corner dominates the image
    assert len(alone) >= 100
    with_spot = klt.detect(spotted, np.zeros((0, 2)), 200)
    assert len(with_spot) >= 0.9 * len(alone)


def test_noise_alone_gives_no_corners():
    rng = np.random.default_rng(1)
    blank = np.clip(120.0 + rng.normal(0.0, 1.0, (240, 320)), 0, 255).astype(np.uint8)
    assert len(KltFrontend(min_corner_response=2e-4).detect(blank, np.zeros((0, 2)), 200)) == 0
