"""A bench campaign station made by a real ``fgcd capture`` on the simulated rig, once per bench campaign.

The faults that hit a whole revisit (whole operations, power loss) need a true
reference: the cloud, images and pose a capture writes, as a user's station
has. The campaign's hand-eye comes from a real ``fgcd calibrate hand-eye``
(:func:`fgcd_cli.bench.faults.campaign_faults.calibrate_campaign`).
"""

from __future__ import annotations

from pathlib import Path

from fgcd_cli.bench.faults.campaign_faults import calibrate_campaign
from fgcd_cli.bench.faults.checks import run_fgcd
from fgcd_cli.campaign import schema

__all__ = ["REAL_STATION", "REAL_STATION_LIGHTS", "prepare_real_station"]

#: The station captured for the revisit faults, and its lightings (two: the revisit's and one more).
REAL_STATION = "real"
REAL_STATION_LIGHTS = "led:3,led:9"


def prepare_real_station(campaign: Path, station: str = REAL_STATION) -> str:
    """Capture ``station`` in the bench campaign with ``fgcd capture`` (once); its name.

    Raises
    ------
    RuntimeError
        The capture failed (the bench cannot run its revisit faults).
    """
    calibrate_campaign(campaign)
    reference = Path(campaign) / schema.STATIONS_DIR / station / schema.REFERENCE_DIR / schema.MANIFEST
    if reference.is_file():
        return station
    run = run_fgcd(
        ["capture", "-c", str(campaign), "-s", station, "--light", REAL_STATION_LIGHTS, "--yes", "--json"],
        timeout_s=1800,
    )
    if run.code != 0 or not reference.is_file():
        raise RuntimeError(f"the bench station's capture failed: {(run.lines or ['?'])[-1]}")
    return station
