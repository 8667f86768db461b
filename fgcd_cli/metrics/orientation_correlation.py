"""Phase correlation of gradient orientations: patch shifts that hold when the light moves.

Under another light a surface's shading changes sign as well as strength: the lit
and shadowed flanks of a groove or a grain swap sides, so grey values and even
gradient magnitudes (clamped shading, cast shadows) differ, while the *lines*
the gradients run along stay where the surface puts them. The doubled-angle
gradient ``z = (g_x + i g_y)^2 / |g|`` keeps exactly that: its phase is twice the
gradient's direction, so a gradient and its opposite (the same edge lit from the
other side) give the same value, and its modulus is the gradient's magnitude, so
strong edges weigh more than noise. Correlating these complex fields measures the
shift of the edges' layout, whatever their polarity (docs/change-detection.md,
"FDF / AFD", grid variant; issue 46, item 2).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["orientation_field", "phase_correlate_orientation"]


def orientation_field(gray: np.ndarray, *, sigma_px: float = 1.0) -> np.ndarray:
    """The doubled-angle gradient of a Gaussian-smoothed grey image.

    Parameters
    ----------
    gray : (H, W) float32 ndarray
    sigma_px : float
        Gaussian pre-smoothing, pixels (as ``changes.registration.gradient_magnitude``).

    Returns
    -------
    (H, W) complex64 ndarray
        ``(g_x + i g_y)^2 / |g|``: modulus ``|g|`` (intensity per pixel), phase twice the gradient's angle.
    """
    smooth = cv2.GaussianBlur(np.asarray(gray, np.float32), (0, 0), sigma_px) if sigma_px > 0 else gray
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)
    z = gx + 1j * gy
    return (z * z / (np.abs(z) + 1e-9)).astype(np.complex64)


def phase_correlate_orientation(a: np.ndarray, b: np.ndarray, window: np.ndarray) -> tuple[tuple[float, float], float]:
    """The shift of patch ``b`` relative to patch ``a`` (content at p in ``a`` is at p + d in ``b``).

    Written by hand: ``cv2.phaseCorrelate`` takes real single-channel patches only. The
    cross-power spectrum of the windowed complex patches is normalised to unit modulus
    (phase correlation); its inverse transform peaks at the shift, refined to sub-pixel
    by a parabola through the peak and its neighbours along each axis.

    Parameters
    ----------
    a, b : (N, N) complex ndarray
        Orientation fields (:func:`orientation_field`) of the two patches.
    window : (N, N) float ndarray
        Apodisation (a Hann window).

    Returns
    -------
    ((dx, dy), response)
        The shift in pixels and the correlation peak (the fraction of the patches' spectral
        phase that agrees on it, in [0, 1], as ``cv2.phaseCorrelate``'s response).
    """
    fa = np.fft.fft2(a * window)
    fb = np.fft.fft2(b * window)
    cross = np.conj(fa) * fb
    cross /= np.abs(cross) + 1e-12
    surface = np.fft.fftshift(np.real(np.fft.ifft2(cross)))
    n_y, n_x = surface.shape
    y, x = np.unravel_index(int(np.argmax(surface)), surface.shape)
    peak = float(surface[y, x])

    def vertex(left: float, right: float) -> float:
        curvature = left - 2.0 * peak + right
        return 0.0 if curvature >= 0 else 0.5 * (left - right) / curvature

    dx = x - n_x // 2 + (vertex(surface[y, x - 1], surface[y, x + 1]) if 0 < x < n_x - 1 else 0.0)
    dy = y - n_y // 2 + (vertex(surface[y - 1, x], surface[y + 1, x]) if 0 < y < n_y - 1 else 0.0)
    return (float(dx), float(dy)), peak
