"""Charts of the reports (matplotlib Agg): a relocation's convergence and a station's history, as figures or PNG bytes."""

from __future__ import annotations

import io

import numpy as np

from fgcd_cli.report.areas import area_mm2_text  # noqa: E402
from fgcd_cli.report.mpl import matplotlib, plt

__all__ = ["convergence_figure", "convergence_png", "figure_png", "history_figure", "history_png"]


def figure_png(fig) -> bytes:
    """PNG bytes of a matplotlib figure (110 dpi, tight bounding box); the figure is closed."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


CONVERGENCE_PANELS = (
    ("afd_est_px", "afd_px_true", "AFD (px)", 3.0),
    ("offset_mm", "pose_err_mm_true", "remaining translation (mm)", None),
    ("offset_deg", "pose_err_deg_true", "remaining rotation (deg)", None),
)
"""Convergence panels: the loop's own estimate column, the simulator-truth column, the axis label and the
success line (rACR's 3 px AFD rule). The estimate is what the tool knew; truth exists only on the simulator."""

ESTIMATE_STYLE = {"color": "#1f5fa8", "marker": "o", "linestyle": "-", "markersize": 3.5}
TRUTH_STYLE = {"color": "#7f7f7f", "marker": "x", "linestyle": "--", "markersize": 4, "linewidth": 1}


def _column(log_rows: list[dict], key: str) -> np.ndarray | None:
    """One column of the log as floats (NaN where missing), or None when no row has it."""
    values = [row.get(key) for row in log_rows]
    if all(v is None for v in values):
        return None
    return np.array([np.nan if v is None else float(v) for v in values])


def _log_scale_if_wide(ax, values: list[np.ndarray]) -> None:
    """A log y axis with plain-number labels when the plotted values span more than 50x."""
    finite = np.concatenate([v[np.isfinite(v)] for v in values])
    if finite.size == 0 or finite.min() <= 0 or finite.max() / finite.min() <= 50:
        return
    ax.set_yscale("log")
    # Plain numbers, no minor-tick labels ("6 x 10^0" clutters a small panel).
    ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())


def convergence_figure(log_rows: list[dict]):
    """The relocation convergence figure (as rACR Fig. 8), one panel per quantity.

    Parameters
    ----------
    log_rows : list of dict
        One per adjustment, keys among ``iteration``, the loop's own estimates
        ``afd_est_px``, ``offset_mm``, ``offset_deg``, and the simulator's truth
        ``afd_px_true``, ``pose_err_mm_true``, ``pose_err_deg_true`` (evaluation only).

    Returns
    -------
    matplotlib.figure.Figure
        Each panel plots the tool's estimate ("estimate", solid blue); the simulator's
        truth, when the log holds it, is added as a dashed grey line labelled
        "simulator truth". Adjustments are whole numbers on the x axis.

    Raises
    ------
    ValueError
        When the log has none of these columns.
    """
    iterations = np.array([row.get("iteration", i) for i, row in enumerate(log_rows)], dtype=float)
    panels = []
    for est_key, true_key, ylabel, line in CONVERGENCE_PANELS:
        est, true = _column(log_rows, est_key), _column(log_rows, true_key)
        if est is not None or true is not None:
            panels.append((est, true, ylabel, line))
    if not panels:
        raise ValueError("relocation log has no AFD or pose column")
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 3.0), squeeze=False)
    for ax, (est, true, ylabel, line) in zip(axes[0], panels):
        if est is not None:
            ax.plot(iterations, est, label="estimate (the tool's own)", **ESTIMATE_STYLE)
        if true is not None:
            ax.plot(iterations, true, label="simulator truth", **TRUTH_STYLE)
        if line is not None:
            ax.axhline(line, color="#c0392b", linestyle=":", linewidth=1, label=f"success limit {line:g} px")
        ax.set_xlabel("adjustment")
        ax.set_ylabel(ylabel, fontsize=8)
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        _log_scale_if_wide(ax, [v for v in (est, true) if v is not None])
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def convergence_png(log_rows: list[dict]) -> bytes:
    """PNG bytes of :func:`convergence_figure`."""
    return figure_png(convergence_figure(log_rows))


HISTORY_MIN_SLOTS = 3
"""The history chart is at least this many visits wide, so that one visit is a bar, not a wall."""


def _area_label(area: float, area_px: int, use_mm2: bool) -> str:
    """A bar's label: the area to the precision its pixels allow, "–" when unknown."""
    if not np.isfinite(area):
        return "–"
    return area_mm2_text(float(area), area_px) if use_mm2 else f"{int(area)} px"


def history_figure(
    dates: list[str], changed_mm2: list[float | None], changed_px: list[int], afd_px: list[float | None]
):
    """Station history: changed area (bars) and AFD after relocation (dots) per visit.

    Both y axes start at 0: the area axis reaches at least 1 (an unchanged visit is a
    flat zero, not a zoom on nothing) and the AFD axis at least the 3 px success limit,
    drawn dotted. The x axis is at least ``HISTORY_MIN_SLOTS`` visits wide.
    """
    fig, ax = plt.subplots(figsize=(7.0, 2.8))
    x = np.arange(len(dates))
    use_mm2 = any(v is not None for v in changed_mm2)
    area = np.array([np.nan if v is None else float(v) for v in (changed_mm2 if use_mm2 else changed_px)])
    bars = ax.bar(x, area, width=0.6, color="#c2185b", alpha=0.8)
    ax.bar_label(
        bars,
        labels=[_area_label(a, p, use_mm2) for a, p in zip(area, changed_px)],
        fontsize=7,
        color="#c2185b",
        padding=2,
    )
    ax.set_ylabel("changed area (mm²)" if use_mm2 else "changed area (px)", fontsize=9, color="#c2185b")
    top = np.nanmax(area) if np.isfinite(area).any() else 0.0
    ax.set_ylim(0, max(1.0, 1.15 * top))
    pad = max(0.0, (HISTORY_MIN_SLOTS - len(dates)) / 2)
    ax.set_xlim(-0.6 - pad, len(dates) - 0.4 + pad)
    ax.set_xticks(
        x, dates, rotation=20 if len(dates) > 1 else 0, fontsize=7, ha="right" if len(dates) > 1 else "center"
    )
    ax2 = ax.twinx()
    afd = np.array([np.nan if v is None else float(v) for v in afd_px])
    ax2.plot(x, afd, "o-", color="#1f5fa8")
    ax2.axhline(3.0, color="#1f5fa8", linestyle=":", linewidth=1)
    afd_top = np.nanmax(afd) if np.isfinite(afd).any() else 0.0
    ax2.set_ylim(0, max(3.3, 1.15 * afd_top))
    ax2.set_ylabel("AFD after relocation (px)\n(dotted: 3 px success limit)", fontsize=8, color="#1f5fa8")
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return fig


def history_png(
    dates: list[str], changed_mm2: list[float | None], changed_px: list[int], afd_px: list[float | None]
) -> bytes:
    """PNG bytes of :func:`history_figure`."""
    return figure_png(history_figure(dates, changed_mm2, changed_px, afd_px))
