"""The uncertainty of a PnP pose from its own reprojection residuals (the image stage's ``offset_sigma_mm``,
paper 001's camera uncertainty of the localizer)."""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["pnp_jacobian", "pnp_translation_sigma_m"]


def pnp_translation_sigma_m(
    points_3d: np.ndarray, pixels: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray
) -> float:
    """1-sigma uncertainty of a PnP translation from its own reprojection residuals, metres.

    Gauss-Newton covariance of the six pose parameters,
    ``Cov = s^2 (J^T J)^-1`` with ``s^2 = sum(r^2) / (2n - 6)`` the residual
    variance per image coordinate and ``J`` (2n, 6) the reprojection Jacobian with
    respect to ``(rvec, tvec)``. The rotation-translation coupling of a nearly
    planar scene (a sideways shift that a small turn almost hides) appears as a
    large marginal translation variance, which is the point.

    Parameters
    ----------
    points_3d : (n, 3) ndarray
        Inlier points in the reference camera frame, metres.
    pixels : (n, 2) ndarray
        Their matched pixels in the current image.
    rvec, tvec : (3,) ndarray
        The PnP pose (reference camera into current camera).
    K : (3, 3) ndarray
        Pinhole matrix.

    Returns
    -------
    float
        ``sqrt(trace(Cov_t))``: the RMS radius of the translation error, metres
        (invariant to the frame it is expressed in). The camera centre
        ``-R^T t`` has the same uncertainty up to the rotation uncertainty times
        the (near-zero) offset. ``inf`` when fewer than 4 points or the
        system is singular.
    """
    n = len(points_3d)
    if n < 4:
        return math.inf
    proj, J = pnp_jacobian(points_3d, rvec, tvec, K)
    r = (proj - np.asarray(pixels, dtype=np.float64)).ravel()
    s2 = float(r @ r) / max(1, 2 * n - 6)
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return math.inf
    return float(math.sqrt(max(0.0, float(np.trace(cov[3:, 3:])))))


def pnp_jacobian(
    points_3d: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Projections (n, 2) of ``points_3d`` (n, 3) under the pose ``(rvec, tvec)`` and the reprojection
    Jacobian (2n, 6) with respect to ``(rvec, tvec)`` (OpenCV's ``projectPoints``, no distortion)."""
    proj, jac = cv2.projectPoints(
        np.asarray(points_3d, dtype=np.float64),
        np.asarray(rvec, dtype=np.float64),
        np.asarray(tvec, dtype=np.float64),
        K,
        None,
    )
    return proj.reshape(-1, 2), jac[:, :6]
