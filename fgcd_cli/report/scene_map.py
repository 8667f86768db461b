"""The scene uncertainty figure of a visit's relocation section (paper 001, Fig. 2's camera-driven map).

A heat map of ``U`` (Eq. 2) over the workspace grid of candidate camera positions, seen from
behind the reference camera (x right, up is up), with the two localizers' success fractions
beside it, the reference camera, and — when the visit ran the coarse stage — the camera
positions its steps estimated (from ``coarse.jsonl``).
"""

from __future__ import annotations

import html

import numpy as np

from fgcd_cli.report.charts import figure_png
from fgcd_cli.report.mpl import plt

__all__ = ["coarse_positions_mm", "scene_uncertainty_figure", "scene_uncertainty_section"]


def coarse_positions_mm(coarse_log: list[dict] | None) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The camera position each coarse step estimated, in the reference camera frame.

    Returns
    -------
    xyz : (S, 3) ndarray
        Millimetres; per step the estimate the step used, else the one logged first.
    verified : (S,) bool ndarray
        Whether the step moved on a verified estimate.
    steps : list of int
        Their step numbers. Steps without a logged position (older logs) are left out.
    """
    xyz, verified, steps = [], [], []
    for row in coarse_log or []:
        estimates = row.get("estimates") or {}
        used = estimates.get(row.get("source") or "") or {}
        pos = used.get("position_refcam_m") or next(
            (e["position_refcam_m"] for e in estimates.values() if isinstance(e, dict) and "position_refcam_m" in e),
            None,
        )
        if pos is None:
            continue
        xyz.append(np.asarray(pos, dtype=float) * 1e3)
        verified.append(bool(row.get("source")))
        steps.append(int(row.get("step", len(steps) + 1)))
    return np.reshape(xyz, (-1, 3)), np.asarray(verified, dtype=bool), steps


def scene_uncertainty_figure(scene_map, coarse_log: list[dict] | None = None):
    """Three panels over the grid layer nearest the reference camera's plane: ``U``, and the fractions
    of directions where the image (PnP) and the 3D localizer are predicted to succeed.

    Parameters
    ----------
    scene_map : SceneUncertaintyMap
    coarse_log : list of dict, optional
        The visit's ``coarse.jsonl`` rows.
    """
    layer = int(np.argmin(np.abs(np.asarray(scene_map.z_m))))
    n = float(scene_map.n_directions)
    panels = (
        ("scene uncertainty U (Eq. 2)", scene_map.uncertainty[layer], "magma"),
        ("image localizer succeeds", scene_map.image_successes[layer] / n, "viridis"),
        ("3D localizer succeeds", scene_map.geometry_successes[layer] / n, "viridis"),
    )
    x_mm, y_mm = np.asarray(scene_map.x_m) * 1e3, np.asarray(scene_map.y_m) * 1e3
    half = (x_mm[1] - x_mm[0]) / 2 if len(x_mm) > 1 else 1.0
    extent = (x_mm[0] - half, x_mm[-1] + half, y_mm[-1] + half, y_mm[0] - half)  # y down: image rows
    xyz, verified, steps = coarse_positions_mm(coarse_log)
    fig, axes = plt.subplots(1, 3, figsize=(12.5, 4.0), constrained_layout=True)
    for ax, (title, values, cmap) in zip(axes, panels):
        im = ax.imshow(values, extent=extent, origin="upper", vmin=0.0, vmax=1.0, cmap=cmap, interpolation="nearest")
        ax.plot(
            [0.0],
            [0.0],
            marker="*",
            color="#2ca02c",
            markersize=14,
            markeredgecolor="white",
            linestyle="none",
            label="reference camera",
        )
        if len(xyz):
            ax.plot(xyz[:, 0], xyz[:, 1], color="#00bcd4", linewidth=1, zorder=3)
            if verified.any():
                ax.scatter(
                    xyz[verified, 0],
                    xyz[verified, 1],
                    s=36,
                    color="#00bcd4",
                    edgecolor="black",
                    zorder=4,
                    label="coarse step, verified estimate",
                )
            if not verified.all():
                ax.scatter(
                    xyz[~verified, 0],
                    xyz[~verified, 1],
                    s=36,
                    facecolor="white",
                    edgecolor="#00bcd4",
                    zorder=4,
                    label="coarse step, unverified estimate",
                )
            for (x, y, _z), k in zip(xyz, steps):
                ax.annotate(str(k), (x, y), textcoords="offset points", xytext=(4, 4), fontsize=8, color="white")
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_title(title + uniform_note(values), fontsize=10)
        ax.set_xlabel("x right of the reference camera (mm)")
        fig.colorbar(im, ax=ax, shrink=0.85)
    axes[0].set_ylabel("y below the reference camera (mm)")
    axes[0].legend(loc="lower left", fontsize=7, framealpha=0.8)
    return fig


def uniform_note(values: np.ndarray) -> str:
    """``"\n(1 % at every position)"`` when a panel's map is one value everywhere, else ``""``.

    A map that is the same everywhere says one thing, not where: the title says it
    (a flat object's 3D localizer, predicted to fail from every position, is a
    computed 0, not a missing map).
    """
    v = np.asarray(values, dtype=float)
    finite = v[np.isfinite(v)]
    if finite.size == 0 or float(finite.max() - finite.min()) > 1e-9:
        return ""
    return f"\n({finite.max():.0%} at every position)"


def scene_uncertainty_section(scene_map, coarse_log: list[dict] | None = None) -> list[str]:
    """The report's scene uncertainty figure with its caption (HTML parts; none without a map)."""
    if scene_map is None:
        return []
    from fgcd_cli.report.figures import data_uri

    png = figure_png(scene_uncertainty_figure(scene_map, coarse_log))
    depth = float(np.asarray(scene_map.z_m)[int(np.argmin(np.abs(np.asarray(scene_map.z_m))))]) * 1e3
    caption = (
        f"Scene uncertainty of the reference (paper 001, Eq. 2): for each candidate camera position on the "
        f"plane {depth:+.0f} mm along the reference camera's axis, U = 1 - the fraction of "
        f"{scene_map.n_directions} view directions (at the object, and turned "
        f"{scene_map.config.spread_deg:g} deg left, right, up, down) from which the image (PnP) or the 3D "
        'localizer is predicted to succeed (docs/relocation.md, "Scene uncertainty"). Seen from behind the '
        "reference camera (green star)."
    )
    if not np.any(np.asarray(scene_map.geometry_successes)):
        caption += (
            " The 3D localizer is predicted to fail from every position: the visible surface leaves a "
            "direction unconstrained (a flat or nearly flat object); the revisit's own 3D alignment, "
            "which starts near the reference, is a different test."
        )
    if coarse_positions_mm(coarse_log)[2]:
        caption += " Cyan: the camera positions the coarse stage estimated, by step (filled: verified)."
    return [
        '<div class="pair"><figure class="wide">'
        f'<img src="{data_uri(png)}" alt="scene uncertainty map">'
        f"<figcaption>{html.escape(caption)}</figcaption></figure></div>"
    ]
