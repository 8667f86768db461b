"""Change over time (``fgcd archive history``): each station's regions tracked across visits, and a site page.

Reads what ``fgcd archive analyze`` (or ``fgcd diff -c``) stored in the visits
(``changes/regions.json``, ``changes/change_mask.png``), follows every region
across the visits (:func:`fgcd_cli.archive.tracking.track_regions`) and writes,
per campaign, a self-contained site page that ranks the stations by new or
growing damage (docs/archive.md, "Change over time"). Visits not analysed yet
are listed, never analysed here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from fgcd_cli.archive.discovery import find_campaigns
from fgcd_cli.archive.tracking import RegionTrack, TrackStatus, VisitRegions, track_regions
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.atomic import atomic_write_bytes
from fgcd_cli.campaign.store import open_campaign
from fgcd_cli.errors import DataIntegrityError, UserInputError

__all__ = [
    "HistoryRequest",
    "StationHistory",
    "SiteHistory",
    "station_tracks",
    "archive_history",
    "track_growth",
    "visit_date",
]

_REGIONS = schema.change_relpath(schema.REGIONS_JSON)
_MASK = schema.change_relpath(schema.CHANGE_MASK_PNG)
_OVERLAY = schema.change_relpath(schema.OVERLAY_PNG)


@dataclass(frozen=True, kw_only=True)
class HistoryRequest:
    """``fgcd archive history ROOT...``: the roots searched for campaigns."""

    roots: list[Path]


@dataclass(kw_only=True)
class StationHistory:
    """One station's regions over time.

    Attributes
    ----------
    campaign, station : str
    analysed, not_analysed : list of str
        Visits with stored analysis products, and visits without.
    dates : dict of str to datetime
    tracks : list of RegionTrack
    unit : str
        ``mm²`` or ``px``.
    new_area, grown_area : float
        At the latest analysed visit: area of the regions first seen there, and
        area added by the growing ones since the visit before (``unit``).
    overlay_png : bytes or None
        The latest analysed visit's change map.
    """

    campaign: str
    station: str
    analysed: list[str] = field(default_factory=list)
    not_analysed: list[str] = field(default_factory=list)
    dates: dict[str, datetime] = field(default_factory=dict)
    tracks: list[RegionTrack] = field(default_factory=list)
    unit: str = "mm²"
    new_area: float = 0.0
    grown_area: float = 0.0
    overlay_png: bytes | None = None

    @property
    def rank_score(self) -> float:
        """New plus grown area at the latest visit: the site page's ranking key (``unit``)."""
        return self.new_area + self.grown_area

    def count_new(self) -> int:
        """Tracks first seen at the latest analysed visit."""
        return sum(t.status == TrackStatus.NEW for t in self.tracks)

    def count_growing(self) -> int:
        """Tracks that grew since the visit before the latest."""
        return sum(t.status == TrackStatus.GROWING for t in self.tracks)

    def to_dict(self) -> dict:
        """JSON-ready form (images left out)."""
        return {
            "campaign": self.campaign,
            "station": self.station,
            "analysed": self.analysed,
            "not_analysed": self.not_analysed,
            "unit": self.unit,
            "new_area": self.new_area,
            "grown_area": self.grown_area,
            "tracks": [t.to_dict() for t in self.tracks],
        }


@dataclass(kw_only=True)
class SiteHistory:
    """A campaign's stations ranked by new or growing damage, and where its page was written."""

    campaign: str
    site: str
    stations: list[StationHistory]
    page: str

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {
            "campaign": self.campaign,
            "site": self.site,
            "page": self.page,
            "stations": [s.to_dict() for s in self.stations],
        }


def track_growth(track: RegionTrack) -> str:
    """A tracked region's growth as the site page writes it: ``+12.3 mm²/year``, or ``–`` (seen at one visit)."""
    from fgcd_cli.report.site import growth_text

    return growth_text(track.growth_per_year, track.unit)


def visit_date(visit) -> datetime:
    """A visit's date: its UTC-stamp name (``20240301T000000000Z``), else its manifest's ``created``, else its mtime."""
    try:
        return datetime.strptime(visit.name[:15], "%Y%m%dT%H%M%S").replace(tzinfo=UTC)
    except ValueError:
        pass
    try:
        created = datetime.fromisoformat(str(visit.manifest.get("created")))
    except ValueError:  # neither: the manifest's file time, the last witness of when the visit was written
        return datetime.fromtimestamp((visit.path / schema.MANIFEST).stat().st_mtime, tz=UTC)
    return created if created.tzinfo else created.replace(tzinfo=UTC)


def _visit_regions(visit) -> VisitRegions:
    from fgcd_cli.campaign.codecs import decode_png

    summary = visit.json(_REGIONS)
    mask = decode_png(visit.bytes(_MASK)) > 0
    return VisitRegions(
        visit=visit.name,
        date=visit_date(visit),
        comparable=bool(summary.get("comparable")),
        regions=list(summary.get("regions") or []),
        mask=mask,
    )


def _latest_gains(history: StationHistory) -> None:
    """New and grown area at the latest comparable visit, from the tracks' statuses."""
    for track in history.tracks:
        if track.status == TrackStatus.NEW:
            history.new_area += track.areas.get(track.first_seen) or 0.0
        elif track.status == TrackStatus.GROWING and track.change_since_previous:
            history.grown_area += track.change_since_previous


def station_tracks(campaign: Path, station: str) -> StationHistory:
    """Track the regions of one station across its analysed visits (reads stored products only)."""
    st = open_campaign(campaign).station(station)
    history = StationHistory(campaign=str(campaign), station=station)
    visits = []
    for name in st.visit_names():
        try:
            visit = st.visit(name)
        except DataIntegrityError:  # a damaged visit is named by its caller (`fgcd report`); the others are tracked
            history.not_analysed.append(name)
            continue
        if (
            visit.has(_REGIONS)
            and visit.has(_MASK)
            and (visit.path / _REGIONS).is_file()
            and (visit.path / _MASK).is_file()
        ):
            visits.append(_visit_regions(visit))
            history.analysed.append(name)
            history.overlay_png = visit.bytes(_OVERLAY) if visit.has(_OVERLAY) else history.overlay_png
        else:
            history.not_analysed.append(name)
    shapes = {v.mask.shape for v in visits}
    if len(shapes) > 1:
        visits = [v for v in visits if v.mask.shape == visits[-1].mask.shape]
    history.tracks = track_regions(visits)
    history.dates = {v.visit: v.date for v in visits}
    history.unit = history.tracks[0].unit if history.tracks else "mm²"
    _latest_gains(history)
    return history


def _site(camp_path: Path) -> SiteHistory:
    from fgcd_cli.report.site import render_site_page

    camp = open_campaign(camp_path)
    stations = [station_tracks(camp.path, name) for name in camp.station_names()]
    stations.sort(key=lambda s: (-s.rank_score, s.station))
    page = camp.path / schema.SITE_REPORT
    atomic_write_bytes(page, render_site_page(site=camp.site, stations=stations).encode("utf-8"))
    return SiteHistory(campaign=str(camp.path), site=camp.site, stations=stations, page=str(page))


def archive_history(request: HistoryRequest) -> list[SiteHistory]:
    """Every campaign under ``request.roots``: its stations' tracks and its site page (``<campaign>/site.html``)."""
    if not request.roots:
        raise UserInputError("give at least one archive root (a folder holding campaigns)")
    campaigns = find_campaigns(request.roots)
    if not campaigns:
        raise UserInputError(f"no campaign (no {schema.CAMPAIGN_FILE}) under {', '.join(map(str, request.roots))}")
    return [_site(path) for path in campaigns]
