"""Use case: a campaign itself (``fgcd campaign init | add-station | list | show | verify``).

Create one (a site and its rig), add a station, list its stations, show its
configuration or one station's observations, and check every manifest and
checksum (the damage report).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fgcd_cli.campaign.store import init_campaign, open_campaign
from fgcd_cli.campaign.verify import counted, verify_campaign_dir

__all__ = [
    "CampaignInit",
    "CampaignOverview",
    "CampaignStations",
    "add_station",
    "campaign_overview",
    "campaign_stations",
    "create_campaign",
    "damage_line",
    "station_observations",
    "verify",
]


@dataclass(frozen=True, kw_only=True)
class CampaignInit:
    """A campaign to create (``fgcd campaign init``).

    Attributes
    ----------
    directory : Path
        The campaign folder to create.
    site, description : str
        The site's name and free text.
    driver : str
        The campaign's rig: sim, grbl, ur or manual (campaign.toml ``[rig]``).
    port, host, baud, camera : optional
        The rig's address, baud rate and camera (``[rig]``; the driver's default when not given).
    """

    directory: Path
    site: str
    description: str = ""
    driver: str = "sim"
    port: str | None = None
    host: str | None = None
    baud: int | None = None
    camera: str | None = None


def create_campaign(request: CampaignInit) -> dict:
    """Create the campaign of ``request``; ``{"campaign", "site", "created"}``."""
    from fgcd_cli.app.rig_options import campaign_rig_section

    r = request
    rig = campaign_rig_section(driver=r.driver, port=r.port, host=r.host, baud=r.baud, camera=r.camera)
    camp = init_campaign(r.directory, site=r.site, description=r.description, rig=rig)
    return {"campaign": str(camp.path), "site": camp.site, "created": True}


def add_station(campaign_dir: Path, name: str, *, description: str = "") -> dict:
    """Add a station (a viewpoint to monitor) to the campaign in ``campaign_dir``; ``{"station", "path"}``."""
    st = open_campaign(campaign_dir).create_station(name, description=description)
    return {"station": st.name, "path": str(st.path)}


def _station_summary(st) -> dict:
    return {
        "name": st.name,
        "description": st.info.get("description", ""),
        "reference": st.has_reference(),
        "visits": st.visit_names(),
    }


@dataclass(frozen=True, kw_only=True)
class CampaignStations:
    """The stations of a campaign (``fgcd campaign list``): each ``{"name", "description", "reference", "visits"}``."""

    site: str
    path: Path
    stations: list[dict]

    def to_dict(self) -> dict:
        """The JSON object ``fgcd campaign list --json`` prints."""
        return {"campaign": str(self.path), "site": self.site, "stations": self.stations}


def campaign_stations(campaign_dir: Path) -> CampaignStations:
    """The stations of the campaign in ``campaign_dir`` with their reference and visits."""
    camp = open_campaign(campaign_dir)
    return CampaignStations(
        site=camp.site, path=camp.path, stations=[_station_summary(camp.station(n)) for n in camp.station_names()]
    )


@dataclass(frozen=True, kw_only=True)
class CampaignOverview:
    """A campaign's configuration (``fgcd campaign show``).

    Attributes
    ----------
    site : str
    path : Path
    config : dict
        campaign.toml, section by section.
    stations : list of str
    rig_records : list of str
        The rig records (``rig/*.json``) by name.
    """

    site: str
    path: Path
    config: dict
    stations: list[str]
    rig_records: list[str]

    def to_dict(self) -> dict:
        """The JSON object ``fgcd campaign show --json`` prints."""
        return {
            "campaign": str(self.path),
            "config": self.config,
            "stations": self.stations,
            "rig_records": self.rig_records,
        }


def campaign_overview(campaign_dir: Path) -> CampaignOverview:
    """The configuration, stations and rig records of the campaign in ``campaign_dir``."""
    camp = open_campaign(campaign_dir)
    return CampaignOverview(
        site=camp.site,
        path=camp.path,
        config=camp.config,
        stations=camp.station_names(),
        rig_records=sorted(p.stem for p in (camp.path / "rig").glob("*.json")),
    )


def station_observations(campaign_dir: Path, station: str) -> dict:
    """One station in detail: ``{"station": its summary, "observations": [{"name", "kind", "created", "files",
    "images", "metadata"}, ...]}``, the reference first."""
    st = open_campaign(campaign_dir).station(station)
    obs = []
    if st.has_reference():
        obs.append(st.reference())
    obs += st.visits()
    rows = [
        {
            "name": o.name,
            "kind": o.kind,
            "created": o.manifest.get("created"),
            "files": len(o.files()),
            "images": o.image_names(),
            "metadata": o.metadata,
        }
        for o in obs
    ]
    return {"station": _station_summary(st), "observations": rows}


def verify(campaign_dir: Path):
    """Check every manifest and checksum of the campaign in ``campaign_dir``; the damage report
    (:class:`fgcd_cli.campaign.verify.VerifyReport`; CampaignError when it is not a campaign)."""
    return verify_campaign_dir(campaign_dir)


def damage_line(report) -> str | None:
    """The error line of a damaged campaign (how many files, the first), or None when ``report`` is OK."""
    if report.ok:
        return None
    n = report.count("error")
    first = next(p for p in report.problems if p.severity == "error")
    return f"{counted(n, 'damaged or missing file')}, first: {first.path} ({first.kind})"
