"""The report use case (``fgcd report``): a station's history across its visits."""

from __future__ import annotations

from pathlib import Path

from fgcd_cli.app.diff import CampaignDiffRequest, Progress, run_campaign
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.atomic import atomic_write_bytes
from fgcd_cli.errors import DataIntegrityError

__all__ = ["station_history"]

_REGIONS = schema.change_relpath(schema.REGIONS_JSON)
_OVERLAY = schema.change_relpath(schema.OVERLAY_PNG)


def _visit_summary(campaign: Path, st, name: str, progress: Progress):
    """One visit's row of the history (compared now when it has no stored diff)."""
    from fgcd_cli.report.station_history import VisitSummary

    observation = st.visit(name)
    if not observation.has(_REGIONS):
        run_campaign(CampaignDiffRequest(campaign=campaign, station=st.name, visit=name), progress=progress)
        observation = st.visit(name)
    summary = observation.json(_REGIONS)
    regions = summary.get("regions", [])
    mm2 = [r.get("area_mm2") for r in regions]
    return VisitSummary(
        name=name,
        date=name,
        comparable=bool(summary.get("comparable")),
        reason=summary.get("reason", ""),
        regions=len(regions),
        changed_px=int(sum(r["area_px"] for r in regions)),
        changed_mm2=float(sum(mm2))
        if regions and all(v is not None for v in mm2)
        else (0.0 if not regions and summary.get("comparable") else None),
        afd_px=(summary.get("afd") or {}).get("afd_px"),
        overlay_png=observation.bytes(_OVERLAY) if observation.has(_OVERLAY) else None,
    )


def station_history(campaign: Path, station: str, *, output: Path | None = None, progress: Progress = None) -> dict:
    """Write a station's history report (every visit against the reference); compares visits not yet compared.

    Rule: one damaged or missing visit does not hide the others. A visit whose
    manifest or files are damaged, or whose folder is gone while ``station.json``
    records it, is named in the result's ``damaged`` list (name, reason) and in the
    page; the good visits are reported. The CLI then exits 4 (README, exit codes).
    """
    from fgcd_cli.campaign.store import open_campaign
    from fgcd_cli.report.figures import png_bytes, to_display_rgb
    from fgcd_cli.report.station_history import VisitSummary, render_station_history

    camp = open_campaign(campaign)
    st = camp.station(station)
    reference = st.reference()
    summaries, damaged = [], []
    for name in sorted({*st.visit_names(), *st.missing_visit_names()}):
        try:
            summaries.append(_visit_summary(campaign, st, name, progress))
        except DataIntegrityError as exc:
            damaged.append({"name": name, "reason": str(exc)})
            summaries.append(
                VisitSummary(name=name, date=name, comparable=False, reason=str(exc), extra={"damaged": True})
            )
    lightings = list(reference.metadata.get("lightings") or reference.image_names())
    reference_png = png_bytes(to_display_rgb(reference.image(lightings[0]))) if lightings else None
    from fgcd_cli.app.archive_history import station_tracks
    from fgcd_cli.report.site import tracks_section

    # each region followed across the visits (docs/archive.md, "Change over time")
    tracks = station_tracks(camp.path, station)
    html_text = render_station_history(
        station=station,
        site=camp.site,
        reference_date=str(reference.manifest.get("created", "")),
        reference_png=reference_png,
        visits=summaries,
        tracks_html=tracks_section(tracks) if summaries else "",
    )
    target = output if output is not None else st.path / schema.HISTORY_REPORT
    atomic_write_bytes(target, html_text.encode())
    good = [s for s in summaries if not s.extra.get("damaged")]
    return {
        "station": station,
        "visits": [s.__dict__ | {"overlay_png": None} for s in good],
        "damaged": damaged,
        "output": str(target),
        "tracks": [t.to_dict() for t in tracks.tracks],
    }
