"""Finding every campaign, station and visit under the roots of an archive (docs/archive.md, "Discovery")."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from fgcd_cli.campaign import schema
from fgcd_cli.campaign.store import open_campaign
from fgcd_cli.errors import UserInputError

__all__ = ["VisitKey", "find_campaigns", "archive_visits"]


@dataclass(frozen=True, order=True)
class VisitKey:
    """One visit of an archive: the unit of work of ``fgcd archive analyze``.

    Attributes
    ----------
    campaign : str
        The campaign's directory (absolute, as a string: the key travels to Dask workers).
    station, visit : str
        The station's name and the visit's directory name (its UTC stamp).
    """

    campaign: str
    station: str
    visit: str

    @property
    def label(self) -> str:
        """``<campaign folder>/<station>/<visit>``, the name a progress line or failure line shows."""
        return f"{Path(self.campaign).name}/{self.station}/{self.visit}"


def find_campaigns(roots: list[Path]) -> list[Path]:
    """Every campaign directory (one holding ``campaign.toml``) at or under ``roots``, sorted, without duplicates.

    A campaign's own folders are not searched further (a campaign holds no
    campaign); hidden folders (``.tmp-*`` writes, ``.git``) are skipped.
    UserInputError when a root does not exist.
    """
    found: set[Path] = set()
    for root in roots:
        root = Path(root)
        if not root.is_dir():
            raise UserInputError(f"{root}: no such directory")
        for current, dirs, files in os.walk(root):
            if schema.CAMPAIGN_FILE in files:
                found.add(Path(current).resolve())
                dirs[:] = []
                continue
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
    return sorted(found)


def archive_visits(campaigns: list[Path]) -> list[VisitKey]:
    """Every committed visit of every station of ``campaigns``, in campaign, station, visit order.

    A campaign that cannot be opened raises its own CampaignError (one line naming it).
    """
    keys = []
    for path in campaigns:
        camp = open_campaign(path)
        for name in camp.station_names():
            station = camp.station(name)
            keys += [VisitKey(str(camp.path.resolve()), name, visit) for visit in station.visit_names()]
    return keys
