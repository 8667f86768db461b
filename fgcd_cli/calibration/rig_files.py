"""Calibration results in the campaign rig: ``<campaign>/rig/intrinsics.json``, ``handeye.json``.

Writes go through :meth:`fgcd_cli.campaign.store.Campaign.write_rig` (atomic,
previous record kept in ``rig/history/``).
"""

from __future__ import annotations

from fgcd_cli.calibration.handeye.result import HandEyeResult
from fgcd_cli.calibration.intrinsics import IntrinsicsResult
from fgcd_cli.campaign import schema
from fgcd_cli.errors import CampaignError
from fgcd_core.camera import PinholeCamera

__all__ = ["save_intrinsics", "load_intrinsics", "load_camera", "save_handeye", "load_handeye"]

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
    try:
        return HandEyeResult.from_dict(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise CampaignError(f"{campaign.rig_path(HANDEYE)} is malformed: {exc}") from None
