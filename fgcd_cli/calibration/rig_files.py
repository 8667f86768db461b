"""Calibration results in the campaign rig: ``<campaign>/rig/intrinsics.json``, ``handeye.json``.

The one reader of both records: the full results (:func:`load_intrinsics`,
:func:`load_handeye`) and what a capture or a revisit needs of them
(:func:`rig_calibration`) parse them through the same two functions.

Writes go through :meth:`fgcd_cli.campaign.store.Campaign.write_rig` (atomic,
previous record kept in ``rig/history/``).
"""

from __future__ import annotations

import numpy as np

from fgcd_cli.calibration.handeye.result import HandEyeResult
from fgcd_cli.calibration.intrinsics import IntrinsicsResult
from fgcd_cli.campaign import schema
from fgcd_cli.errors import CampaignError
from fgcd_core.camera import PinholeCamera

__all__ = [
    "load_camera",
    "load_handeye",
    "load_intrinsics",
    "rig_calibration",
    "save_handeye",
    "save_intrinsics",
]

INTRINSICS = schema.RIG_INTRINSICS
HANDEYE = schema.RIG_HANDEYE


def save_intrinsics(campaign, result: IntrinsicsResult) -> str:
    """Store an intrinsic calibration; returns the path written."""
    return str(campaign.write_rig(INTRINSICS, result.to_dict()))


def load_intrinsics(campaign) -> IntrinsicsResult | None:
    """The stored intrinsic calibration, or None."""
    data = campaign.read_rig(INTRINSICS)
    if data is None:
        return None
    _camera_of(campaign, data)
    try:
        return IntrinsicsResult.from_dict(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise CampaignError(f"{campaign.rig_path(INTRINSICS)} is malformed: {exc}") from None


def load_camera(campaign) -> PinholeCamera:
    """Calibrated intrinsics of the campaign's camera; a clear error if not calibrated."""
    result = load_intrinsics(campaign)
    if result is None:
        raise CampaignError(
            f"the camera of {campaign.path} is not calibrated: run `fgcd calibrate intrinsics --campaign {campaign.path}` first"
        )
    return result.camera


def save_handeye(campaign, result: HandEyeResult, *, extra: dict | None = None) -> str:
    """Store a hand-eye calibration (with its residuals, method and time); returns the path."""
    record = result.to_dict()
    if extra:
        record.update(extra)
    return str(campaign.write_rig(HANDEYE, record))


def load_handeye(campaign) -> HandEyeResult | None:
    """The stored hand-eye calibration, or None."""
    data = campaign.read_rig(HANDEYE)
    if data is None:
        return None
    _T_flange_cam_of(campaign, data)
    try:
        return HandEyeResult.from_dict(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise CampaignError(f"{campaign.rig_path(HANDEYE)} is malformed: {exc}") from None


def rig_calibration(campaign) -> tuple[np.ndarray | None, PinholeCamera | None]:
    """Hand-eye and intrinsics stored in the campaign rig (None when absent): what a capture or revisit needs.

    Returns
    -------
    T_flange_cam : (4, 4) ndarray or None
        ``rig/handeye.json``'s hand-eye (metres).
    camera : PinholeCamera or None
        ``rig/intrinsics.json``'s camera model (its ``camera`` entry, or the record itself).
    """
    he = campaign.read_rig(HANDEYE)
    intr = campaign.read_rig(INTRINSICS)
    return (None if he is None else _T_flange_cam_of(campaign, he)), (
        None if intr is None else _camera_of(campaign, intr)
    )


def _T_flange_cam_of(campaign, record: dict) -> np.ndarray:
    """A hand-eye record's ``T_flange_cam`` (4, 4); CampaignError naming the record when it has none."""
    try:
        T = np.array(record["T_flange_cam"], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise CampaignError(f"{campaign.rig_path(HANDEYE)} has no T_flange_cam: calibrate again") from None
    if T.shape != (4, 4):
        raise CampaignError(f"{campaign.rig_path(HANDEYE)}: T_flange_cam is not a 4 x 4 matrix: calibrate again")
    return T


def _camera_of(campaign, record: dict) -> PinholeCamera:
    """An intrinsics record's camera model (its ``camera`` entry, or the record itself); CampaignError if none."""
    try:
        return PinholeCamera.from_dict(record.get("camera", record))
    except (KeyError, TypeError, ValueError):
        raise CampaignError(f"{campaign.rig_path(INTRINSICS)} is not a camera model: calibrate again") from None
