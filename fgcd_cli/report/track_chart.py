"""The change-over-time chart of a station: each tracked region's area against the visit date (matplotlib Agg)."""

from __future__ import annotations

from datetime import datetime, timedelta

import matplotlib.dates as mdates

from fgcd_cli.report.charts import figure_png
from fgcd_cli.report.mpl import plt

__all__ = ["track_area_figure", "track_area_png"]

_COLOURS = ("#c2185b", "#1f5fa8", "#2e7d32", "#ef6c00", "#6a1b9a", "#00838f", "#5d4037", "#9e9d24")


def track_area_figure(
    tracks: list, dates: dict[str, datetime], *, unit: str, max_tracks: int = 8, size: tuple[float, float] = (6.0, 2.8)
):
    """Area per tracked region against date, one line per region (the largest ``max_tracks``).

    Parameters
    ----------
    tracks : list of RegionTrack
        :func:`fgcd_cli.archive.tracking.track_regions`' output.
    dates : dict of str to datetime
        Every analysed visit's date (the x axis spans them all).
    unit : str
        ``mm²`` or ``px``.
    """
    fig, ax = plt.subplots(figsize=size)
    shown = sorted(tracks, key=lambda t: -max((a or 0.0) for a in t.areas.values()))[:max_tracks]
    for i, track in enumerate(sorted(shown, key=lambda t: t.id)):
        points = [(dates[v], a) for v, a in track.areas.items() if a is not None]
        if points:
            x, y = zip(*points)
            ax.plot(
                x,
                y,
                "o-",
                color=_COLOURS[i % len(_COLOURS)],
                markersize=4,
                label=f"region {track.id} ({track.status.value})",
            )
    if dates:
        first, last = min(dates.values()), max(dates.values())
        pad = max((last - first) * 0.06, timedelta(days=5))  # the first and last points stay inside the frame
        ax.set_xlim(first - pad, last + pad)
    ax.xaxis.set_major_formatter(mdates.DateFormatter("%Y-%m-%d"))
    ax.tick_params(axis="x", labelsize=7, rotation=20)
    top = max([a or 0.0 for t in shown for a in t.areas.values()] + [0.0])
    ax.set_ylim(0, max(1.0, 1.15 * top))
    ax.set_ylabel(f"area ({unit})", fontsize=9)
    ax.grid(alpha=0.3)
    if shown:
        ax.legend(fontsize=7, loc="upper left")
    else:
        ax.text(
            0.5, 0.5, "no change region at any visit", ha="center", va="center", transform=ax.transAxes, color="#666"
        )
    fig.tight_layout()
    return fig


def track_area_png(tracks: list, dates: dict[str, datetime], *, unit: str) -> bytes:
    """PNG bytes of :func:`track_area_figure` at its default size."""
    return figure_png(track_area_figure(tracks, dates, unit=unit))
