"""Phase correlation of gradient orientations against synthetic truth."""

import cv2
import numpy as np
import pytest

from fgcd_cli.metrics.orientation_correlation import orientation_field, phase_correlate_orientation


def _grooves(shape=(128, 128), seed=0) -> np.ndarray:
    """A height field of random grooves (its relief, not its shading)."""
    rng = np.random.default_rng(seed)
    height = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), 2.0)
    return height / height.std()


def _shade(height: np.ndarray, light_x: float) -> np.ndarray:
    """Lambert-like shading of the relief under a light from the side: brightness follows the x slope."""
    slope_x = cv2.Sobel(height, cv2.CV_32F, 1, 0, ksize=3)
    return (0.5 + 0.1 * light_x * slope_x).astype(np.float32)


def _shifted(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """``image`` with its content moved by (dx, dy) pixels (Lanczos)."""
    M = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(image, M, image.shape[::-1], flags=cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize("dx, dy", [(0.0, 0.0), (2.3, -1.6), (-4.7, 3.2)])
def test_the_shift_of_a_relief_lit_from_the_opposite_side_is_measured(dx, dy):
    height = _grooves()
    morning = _shade(height, light_x=+1.0)
    evening = _shade(_shifted(height, dx, dy), light_x=-1.0)  # the shading reversed, the relief moved
    # The two images are anti-correlated: grey values say the opposite of the truth.
    assert np.corrcoef(morning.ravel(), _shade(height, -1.0).ravel())[0, 1] < -0.99
    window = cv2.createHanningWindow(morning.shape[::-1], cv2.CV_32F)
    (mx, my), response = phase_correlate_orientation(orientation_field(morning), orientation_field(evening), window)
    assert abs(mx - dx) < 0.15 and abs(my - dy) < 0.15
    assert response > 0.3


def test_unrelated_patches_give_a_low_response():
    window = cv2.createHanningWindow((128, 128), cv2.CV_32F)
    a = orientation_field(_shade(_grooves(seed=1), 1.0))
    b = orientation_field(_shade(_grooves(seed=2), 1.0))
    _, response = phase_correlate_orientation(a, b, window)
    assert response < 0.1  # the grid's bar (FdfConfig.min_response)


def test_the_field_keeps_the_gradient_magnitude_and_doubles_its_angle():
    ramp = np.tile(np.linspace(0, 1, 64, dtype=np.float32), (64, 1))  # gradient along +x
    z = orientation_field(ramp, sigma_px=0.0)[32, 32]
    z_reversed = orientation_field(ramp[:, ::-1].copy(), sigma_px=0.0)[32, 32]  # gradient along -x
    assert z.real > 0 and abs(z.imag) < 1e-6 * abs(z)
    assert z_reversed == pytest.approx(z, rel=1e-5)
