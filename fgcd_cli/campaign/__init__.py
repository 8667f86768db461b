"""Campaign, station and observation: the on-disk format with atomic writes and checksums."""

from fgcd_cli.campaign.store import (
    FORMAT_VERSION,
    Campaign,
    Observation,
    ObservationWriter,
    Station,
    init_campaign,
    open_campaign,
    utc_stamp,
)
from fgcd_cli.campaign.verify import VerifyReport, verify_campaign

__all__ = [
    "FORMAT_VERSION",
    "Campaign",
    "Observation",
    "ObservationWriter",
    "Station",
    "VerifyReport",
    "init_campaign",
    "open_campaign",
    "utc_stamp",
    "verify_campaign",
]
