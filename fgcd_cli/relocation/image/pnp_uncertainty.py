"""The uncertainty of a PnP pose from its own reprojection residuals (the image stage's ``offset_sigma_mm``,
paper 001's camera uncertainty of the localizer)."""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["pnp_jacobian", "pnp_translation_sigma_m"]


def pnp_translation_sigma_m(
    points_3d: np.ndarray,
    pixels: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    K: np.ndarray,
    *,
    common_px: float = 0.0,
) -> float:
    """1-sigma uncertainty of a PnP translation from its own reprojection residuals and a common error, metres.

    Gauss-Newton covariance of the six pose parameters,
    ``Cov = s^2 (J^T J)^-1`` with ``s^2 = sum(r^2) / (2n - 6)`` the residual
    variance per image coordinate and ``J`` (2n, 6) the reprojection Jacobian with
    respect to ``(rvec, tvec)``. The rotation-translation coupling of a nearly
    planar scene (a sideways shift that a small turn almost hides) appears as a
    large marginal translation variance, which is the point.

    Independent residuals average out over many matches; an error every match shares
    does not. Registration across lightings has one (the lit and shadowed flanks of every
    groove swap sides: docs/relocation.md, "Stop rules", Uncertainties), modelled as a common image shift
    of ``common_px`` per axis added to every match: the pixel covariance is
    ``s^2 I + common_px^2 A A^T`` with ``A`` (2n, 2) stacking one 2x2 identity per match,
    propagated as ``(J^T J)^-1 J^T Cov_pix J (J^T J)^-1``.

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
    common_px : float
        Standard deviation (pixels, per image axis) of an error shared by every match.

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
        JtJ_inv = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return math.inf
    cov = s2 * JtJ_inv
    if common_px > 0:
        # J^T A: the pose's response to a unit shift of every match along x and along y, (6, 2)
        JtA = np.stack([J[0::2].sum(axis=0), J[1::2].sum(axis=0)], axis=1)
        G = JtJ_inv @ JtA
        cov = cov + common_px**2 * (G @ G.T)
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
