"""The PnP fit of the image stage: RANSAC (SQPnP) on one reference image's 2D-3D matches, then
Levenberg-Marquardt on its inliers (:func:`pnp_fit`, used by :mod:`fgcd_cli.relocation.image.refine`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.relocation.image.pnp_uncertainty import pnp_translation_sigma_m
from fgcd_core.se3 import make_pose

__all__ = ["PnpFit", "pnp_fit"]


@dataclass(frozen=True, kw_only=True)
class PnpFit:
    """A RANSAC PnP fit of one reference image's 2D-3D matches, refined on its inliers.

    ``inliers`` (K,) indices into the matches; ``rms_px`` the inliers' reprojection RMS and ``afd_px`` their
    mean image displacement, px; ``M_cam`` (4, 4) the camera motion to the reference pose, metres;
    ``offset_sigma_mm`` its translation's standard deviation.
    """

    inliers: np.ndarray
    rms_px: float
    afd_px: float
    M_cam: np.ndarray
    offset_sigma_mm: float


def pnp_fit(
    X: np.ndarray,
    p_ref: np.ndarray,
    p_cur: np.ndarray,
    K: np.ndarray,
    *,
    ransac_px: float,
    min_inliers: int,
    common_px: float = 0.0,
) -> tuple[int, PnpFit | None]:
    """PnP with RANSAC (SQPnP), then Levenberg-Marquardt on the inliers.

    ``X`` (M, 3) reference-camera points, metres; ``p_ref``, ``p_cur`` (M, 2) pixels; ``K`` (3, 3);
    ``common_px`` the error every match shares (:func:`pnp_translation_sigma_m`). Returns the number of
    RANSAC inliers and the fit, None when RANSAC failed or found fewer than ``min_inliers``.
    """
    ok, rvec, tvec, inl = cv2.solvePnPRansac(
        X,
        p_cur,
        K,
        None,
        iterationsCount=500,
        reprojectionError=float(ransac_px),
        confidence=0.999,
        flags=cv2.SOLVEPNP_SQPNP,
    )
    found = 0 if inl is None else len(inl)
    if not ok or inl is None or found < min_inliers:
        return found, None
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(X[inl], p_cur[inl], K, None, rvec, tvec)
    proj, _ = cv2.projectPoints(X[inl], rvec, tvec, K, None)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - p_cur[inl]) ** 2, axis=1))))
    afd = float(np.mean(np.linalg.norm(p_cur[inl] - p_ref[inl], axis=1)))
    # (rvec, tvec) maps reference-camera coordinates into the current camera: T_cur_camref,
    # i.e. the reference camera seen from the current one = the motion the camera must make.
    M_cam = make_pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
    sigma_mm = 1000.0 * pnp_translation_sigma_m(X[inl], p_cur[inl], rvec, tvec, K, common_px=common_px)
    return found, PnpFit(inliers=inl, rms_px=rms, afd_px=afd, M_cam=M_cam, offset_sigma_mm=sigma_mm)
