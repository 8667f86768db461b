"""A correction beyond what ordinary image evidence moves: one ordinary step toward it, and the next measurement
must corroborate it (docs/relocation.md, "A large correction on ordinary evidence").

An image (PnP) correction larger than ``ImageRefineConfig.max_motion_*`` is trusted only on strong evidence,
because a chance fit on weak texture could send the camera far. Where neither strong evidence nor the 3D
geometry can vouch for it (the image fallback, or the alignment set aside), the image stage may move by the
largest step ordinary evidence moves (``ImageRefinement.step_M_cam``) toward it and measure again. The
camera's motion is known (the platform's kinematics and the hand-eye), so the first measurement predicts the
second: the camera stands where the first put it, moved by the step. A chance fit does not predict the next
fit from another viewpoint; a real estimate does, within both uncertainties
(:func:`~fgcd_cli.relocation.stop_rule.estimates_agree`). Agreement corroborates it; disagreement ends the
stage. A wrong estimate costs one ordinary step, as it does on ordinary evidence.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcd_cli.relocation.stop_rule import estimates_agree, offset_vector_mm
from fgcd_core.se3 import invert_pose

__all__ = ["Prediction", "corroborates", "predict_after_step"]


@dataclass(frozen=True, kw_only=True)
class Prediction:
    """Where an image estimate puts the camera after a known step.

    Attributes
    ----------
    T_ref_cam : (4, 4) ndarray
        The camera after the step, ``ref`` frame, metres.
    sigma_mm : float
        The estimate's 1-sigma uncertainty (RMS radius), mm.
    """

    T_ref_cam: np.ndarray
    sigma_mm: float


def predict_after_step(
    T_ref_camref: np.ndarray, M_cam: np.ndarray, step_M_cam: np.ndarray, *, sigma_mm: float
) -> Prediction:
    """The camera after moving by ``step_M_cam`` (its own frame), as the estimate ``M_cam`` places it now.

    Parameters
    ----------
    T_ref_camref : (4, 4) ndarray
        The reference camera, ``ref`` frame, metres.
    M_cam : (4, 4) ndarray
        The measured motion to the reference pose, current camera frame (the reference camera seen from the
        current one).
    step_M_cam : (4, 4) ndarray
        The motion made, current camera frame.
    sigma_mm : float
        The measurement's 1-sigma uncertainty, mm.
    """
    T_ref_cam = np.asarray(T_ref_camref, dtype=float) @ invert_pose(np.asarray(M_cam, dtype=float))
    return Prediction(T_ref_cam=T_ref_cam @ np.asarray(step_M_cam, dtype=float), sigma_mm=float(sigma_mm))


def corroborates(
    prediction: Prediction, T_ref_camref: np.ndarray, M_cam: np.ndarray, *, sigma_mm: float, k: float
) -> tuple[bool, float, float]:
    """Whether a new measurement ``M_cam`` (uncertainty ``sigma_mm``) puts the camera where ``prediction`` does.

    Returns
    -------
    agree : bool
    distance_mm, bound_mm : float
        As :func:`~fgcd_cli.relocation.stop_rule.estimates_agree` (``k`` times both uncertainties).
    """
    T_ref_cam = np.asarray(T_ref_camref, dtype=float) @ invert_pose(np.asarray(M_cam, dtype=float))
    return estimates_agree(
        offset_vector_mm(T_ref_cam, T_ref_camref),
        sigma_mm,
        offset_vector_mm(prediction.T_ref_cam, T_ref_camref),
        prediction.sigma_mm,
        k=k,
    )
