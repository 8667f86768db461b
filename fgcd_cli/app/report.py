"""The report use case (``fgcd report``): a station's history across its visits."""

from __future__ import annotations

from pathlib import Path

from fgcd_cli.app.diff import CampaignDiffRequest, Progress, run_campaign
from fgcd_cli.campaign import schema
from fgcd_cli.campaign.atomic import atomic_write_bytes

__all__ = ["station_history"]

_REGIONS = schema.change_relpath(schema.REGIONS_JSON)
_OVERLAY = schema.change_relpath(schema.OVERLAY_PNG)


def station_history(campaign: Path, station: str, *, output: Path | None = None, progress: Progress = None) -> dict:
    """Write a station's history report (every visit against the reference); compares visits not yet compared."""
    from fgcd_cli.campaign import open_campaign
    from fgcd_cli.report.figures import png_bytes, to_display_rgb
    from fgcd_cli.report.html import VisitSummary, render_station_history

    camp = open_campaign(campaign)
    st = camp.station(station)
    reference = st.reference()
    summaries = []
    for name in st.visit_names():
        observation = st.visit(name)
        if not observation.has(_REGIONS):
            run_campaign(CampaignDiffRequest(campaign=campaign, station=station, visit=name), progress=progress)
            observation = st.visit(name)
        summary = observation.json(_REGIONS)
        regions = summary.get("regions", [])
        mm2 = [r.get("area_mm2") for r in regions]
        summaries.append(VisitSummary(
            name=name,
            date=name,
            comparable=bool(summary.get("comparable")),
            reason=summary.get("reason", ""),
            regions=len(regions),
            changed_px=int(sum(r["area_px"] for r in regions)),
            changed_mm2=float(sum(mm2)) if regions and all(v is not None for v in mm2) else (0.0 if not regions and summary.get("comparable") else None),
            afd_px=(summary.get("afd") or {}).get("afd_px"),
            overlay_png=observation.bytes(_OVERLAY) if observation.has(_OVERLAY) else None,
        ))
    lightings = list(reference.metadata.get("lightings") or reference.image_names())
    reference_png = png_bytes(to_display_rgb(reference.image(lightings[0]))) if lightings else None
    from fgcd_cli.app.archive_history import station_tracks
    from fgcd_cli.report.site import tracks_section

    tracks = station_tracks(camp.path, station)  # each region followed across the visits (docs/archive.md)
    html_text = render_station_history(station=station, site=camp.site, reference_date=str(reference.manifest.get("created", "")),
                                       reference_png=reference_png, visits=summaries,
                                       tracks_html=tracks_section(tracks) if summaries else "")
    target = output if output is not None else st.path / schema.HISTORY_REPORT
    atomic_write_bytes(target, html_text.encode())
    return {"station": station, "visits": [s.__dict__ | {"overlay_png": None} for s in summaries], "output": str(target),
            "tracks": [t.to_dict() for t in tracks.tracks]}
