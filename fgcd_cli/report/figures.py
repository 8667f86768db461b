"""Figures of the change reports, as RGB arrays or PNG bytes (matplotlib Agg, OpenCV drawing)."""

from __future__ import annotations

import base64
import io

import cv2
import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fgcd_cli.changes.regions import ChangeRegion  # noqa: E402
from fgcd_cli.changes.significance import SignificantRegion  # noqa: E402

# Colours (RGB) chosen to stand out on plaster, pigments and stone.
CHANGE_RGB = (255, 0, 200)
SET_ASIDE_RGB = (0, 220, 255)  # cyan: found, then set aside by the edge check
LABEL_RGB = (255, 255, 0)
CANDIDATE_RGB = (255, 150, 0)  # amber, dashed and half-transparent: strongest regions not reported
CANDIDATE_ALPHA = 0.6
CUE_RGB = {
    "relief": (60, 110, 255),  # blue: surface normals changed (pits, flakes, cracks)
    "colour": (0, 190, 90),  # green: albedo changed (stains, salts, fading)
    "both": CHANGE_RGB,
}
"""Tint of a reported region by its cue; a region without a cue is tinted ``CHANGE_RGB``."""
CUE_NAMES = {"relief": "blue", "colour": "green", "both": "magenta"}
"""Colour names of ``CUE_RGB``, for legends."""


def to_display_rgb(image: np.ndarray) -> np.ndarray:
    """Any image (grey/RGB, uint8/uint16/float in [0, 1]) as HxWx3 uint8 RGB."""
    array = np.asarray(image)
    if np.issubdtype(array.dtype, np.integer):
        array = array.astype(np.float32) / float(np.iinfo(array.dtype).max)
    array = np.clip(array.astype(np.float32), 0.0, 1.0)
    if array.ndim == 2:
        array = np.repeat(array[:, :, None], 3, axis=2)
    return (array[:, :, :3] * 255.0 + 0.5).astype(np.uint8)


def png_bytes(rgb: np.ndarray) -> bytes:
    """Encode an RGB (or grey) uint8/uint16 array as PNG bytes."""
    array = rgb if rgb.ndim == 2 else cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    ok, buffer = cv2.imencode(".png", array)
    if not ok:
        raise ValueError("PNG encoding failed")
    return buffer.tobytes()


def data_uri(png: bytes) -> str:
    """A ``data:`` URI embedding PNG bytes (for self-contained HTML)."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _figure_png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def candidate_radius_px(area_px: float, shape: tuple[int, ...]) -> int:
    """Radius of a candidate's circle: 1.5x that of a disc of its area, at least 1 % of the image (5 px)."""
    return int(round(max(1.5 * np.sqrt(max(area_px, 0) / np.pi), min(shape[:2]) / 100, 5)))


def _dashed_circle(out: np.ndarray, centre: tuple[int, int], radius: int, colour: tuple[int, int, int], *,
                   dashes: int = 16) -> None:
    """A thin dashed circle (``dashes`` arcs drawn, as many gaps) on ``out``, in place."""
    step = 360.0 / (2 * max(dashes, 4))
    for k in range(0, 2 * max(dashes, 4), 2):
        cv2.ellipse(out, centre, (radius, radius), 0, k * step, (k + 1) * step, colour, 1, cv2.LINE_AA)


def _draw_candidates(out: np.ndarray, candidates: list[SignificantRegion]) -> np.ndarray:
    """``out`` with faint dashed amber circles at the candidates, labelled c1, c2, ... in small thin type."""
    layer = out.copy()
    scale = max(0.35, min(out.shape[:2]) / 1400)
    for k, candidate in enumerate(candidates, start=1):
        cx, cy = (int(round(v)) for v in candidate.centroid_xy)
        radius = candidate_radius_px(candidate.area_px, out.shape)
        _dashed_circle(layer, (cx, cy), radius, CANDIDATE_RGB)
        text = f"c{k}"
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
        tx = int(min(max(cx + int(0.75 * radius) + 2, 0), out.shape[1] - tw - 2))
        ty = int(min(max(cy - int(0.75 * radius), th + 2), out.shape[0] - 2))
        cv2.putText(layer, text, (tx, ty), cv2.FONT_HERSHEY_SIMPLEX, scale, CANDIDATE_RGB, 1, cv2.LINE_AA)
    return cv2.addWeighted(layer, CANDIDATE_ALPHA, out, 1.0 - CANDIDATE_ALPHA, 0.0)


def change_overlay(image: np.ndarray, labels: np.ndarray, regions: list[ChangeRegion], *, valid: np.ndarray | None = None,
                   set_aside: np.ndarray | None = None, candidates: list[SignificantRegion] | None = None) -> np.ndarray:
    """The reference image with changed regions tinted, outlined and numbered.

    Parameters
    ----------
    image : ndarray, HxW or HxWx3, reference image.
    labels : ndarray, HxW int, region id per pixel (0 = unchanged).
    regions : list of ChangeRegion (their ids are drawn next to them). A region with a
        ``cue`` is tinted by it (``CUE_RGB``: relief blue, colour green, both magenta);
        without one, magenta.
    valid : ndarray, HxW bool, optional; pixels outside are dimmed (not compared).
    set_aside : ndarray, HxW bool, optional; regions found but set aside (edge check),
        outlined thinly in cyan and not numbered, so that nothing is hidden.
    candidates : list of SignificantRegion, optional; the strongest regions that were not
        reported, drawn as thin dashed half-transparent amber circles (radius 1.5x that of
        a disc of their area) labelled c1, c2, ... in small type: seen, never mistaken for a
        reported region (tinted, outlined, numbered in yellow).

    Returns
    -------
    ndarray, HxWx3 uint8 RGB.
    """
    rgb = to_display_rgb(image).astype(np.float32)
    if valid is not None:
        rgb[~valid] *= 0.35
    changed = labels > 0
    colour_of = np.zeros(int(labels.max()) + 1, np.int32)  # 0: CHANGE_RGB, k: k-th colour of CUE_RGB
    palette = [CHANGE_RGB, *CUE_RGB.values()]
    for region in regions:
        if region.cue in CUE_RGB and region.id < colour_of.size:
            colour_of[region.id] = 1 + list(CUE_RGB).index(region.cue)
    colour_index = colour_of[np.maximum(labels, 0)]
    tint = np.asarray(palette, np.float32)[colour_index]
    rgb[changed] = 0.55 * rgb[changed] + 0.45 * tint[changed]
    out = np.clip(rgb, 0, 255).astype(np.uint8)
    if candidates:
        out = _draw_candidates(out, candidates)
    thickness = max(1, int(round(min(image.shape[:2]) / 500)))
    if set_aside is not None and set_aside.any():
        aside, _ = cv2.findContours(set_aside.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(out, aside, -1, SET_ASIDE_RGB, 1)
    for k, colour in enumerate(palette):
        group = changed & (colour_index == k)
        if group.any():
            contours, _ = cv2.findContours(group.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(out, contours, -1, colour, thickness)
    scale = max(0.45, min(image.shape[:2]) / 900)
    for region in regions:
        x, y, w, h = region.bbox_xywh
        text = str(region.id)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 2)
        tx = int(min(max(x + w + 2, 0), out.shape[1] - tw - 2))
        ty = int(min(max(y + th, th + 2), out.shape[0] - 2))
        cv2.putText(out, text, (tx, ty), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 4, cv2.LINE_AA)
        cv2.putText(out, text, (tx, ty), cv2.FONT_HERSHEY_SIMPLEX, scale, LABEL_RGB, 2, cv2.LINE_AA)
    return out


def score_heatmap(score: np.ndarray, valid: np.ndarray, *, high: float | None = None) -> np.ndarray:
    """Change score as an RGB heat map (magma), saturating at ``high`` (default: 99.9th percentile)."""
    values = score[valid] if valid.any() else score.ravel()
    top = high if high is not None and high > 0 else float(np.percentile(values, 99.9)) or 1.0
    normalized = np.clip(score / top, 0.0, 1.0)
    rgb = (plt.get_cmap("magma")(normalized)[:, :, :3] * 255).astype(np.uint8)
    rgb[~valid] = (40, 40, 40)
    return rgb


def fdf_quiver_png(ref_image: np.ndarray, points_ref: np.ndarray, points_cur: np.ndarray, *, afd_px: float,
                   inliers: int, method: str, max_arrows: int = 400) -> bytes:
    """FDF quiver figure: displacement vectors drawn on the reference image, AFD in the title.

    Arrows are magnified so that the median one is ~4 % of the image width; the
    magnification is printed on the figure (a 2 px vector would be invisible otherwise).
    """
    rgb = to_display_rgb(ref_image)
    h, w = rgb.shape[:2]
    disp = points_cur - points_ref
    if len(points_ref) > max_arrows:
        keep = np.random.default_rng(0).choice(len(points_ref), max_arrows, replace=False)
        pts, disp = points_ref[keep], disp[keep]
    else:
        pts = points_ref
    lengths = np.linalg.norm(disp, axis=1)
    median = float(np.median(lengths)) if lengths.size else 0.0
    magnify = max(1.0, round(0.04 * w / median)) if median > 0 else 1.0
    fig, ax = plt.subplots(figsize=(6.4, 6.4 * h / w))
    ax.imshow(rgb, cmap="gray")
    if len(pts):
        ax.quiver(pts[:, 0], pts[:, 1], disp[:, 0] * magnify, disp[:, 1] * magnify, angles="xy", scale_units="xy",
                  scale=1, color="#ffd400", width=0.004, headwidth=4)
    ax.set_title(f"FDF ({method}): AFD = {afd_px:.2f} px, {inliers} vectors, arrows x{magnify:g}", fontsize=10)
    ax.set_axis_off()
    return _figure_png(fig)


def convergence_png(log_rows: list[dict]) -> bytes:
    """Relocation convergence curves (as rACR Fig. 8): AFD and pose error per adjustment.

    Parameters
    ----------
    log_rows : list of dict
        One per adjustment, keys among ``iteration``, ``t_wall_s``, ``afd_px`` /
        ``afd_px_true``, ``pose_err_mm_true`` / ``pose_err_mm`` / ``offset_mm`` (the loop's own
        estimate), ``pose_err_deg_true`` / ``pose_err_deg`` / ``offset_deg``.
    """
    def series(*keys):
        for key in keys:
            values = [row.get(key) for row in log_rows]
            if any(v is not None for v in values):
                return key, np.array([np.nan if v is None else float(v) for v in values])
        return None, None

    iterations = np.array([row.get("iteration", i) for i, row in enumerate(log_rows)], dtype=float)
    panels = [
        (series("afd_px", "afd_px_true"), "AFD (px)", 3.0, "success AFD < 3 px"),
        (series("pose_err_mm", "pose_err_mm_true", "offset_mm"), "translation error (mm)", None, None),
        (series("pose_err_deg", "pose_err_deg_true", "offset_deg"), "rotation error (deg)", None, None),
    ]
    panels = [p for p in panels if p[0][0] is not None]
    if not panels:
        raise ValueError("relocation log has no AFD or pose error column")
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 3.0), squeeze=False)
    for ax, ((key, values), ylabel, line, line_label) in zip(axes[0], panels):
        ax.plot(iterations, values, "o-", color="#1f5fa8", markersize=3)
        if line is not None:
            ax.axhline(line, color="#c0392b", linestyle="--", linewidth=1, label=line_label)
            ax.legend(fontsize=8)
        ax.set_xlabel("adjustment")
        note = " [simulator truth]" if key.endswith("_true") else (" [estimated offset]" if key.startswith("offset") else "")
        ax.set_ylabel(ylabel + note, fontsize=8)
        if np.nanmin(values) > 0 and np.nanmax(values) / max(np.nanmin(values), 1e-9) > 50:
            ax.set_yscale("log")
            # Plain numbers, no minor-tick labels ("6 x 10^0" clutters a small panel).
            ax.yaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return _figure_png(fig)


def history_png(dates: list[str], changed_mm2: list[float | None], changed_px: list[int], afd_px: list[float | None]) -> bytes:
    """Station history: changed area and AFD per visit."""
    fig, ax = plt.subplots(figsize=(7.0, 2.8))
    x = np.arange(len(dates))
    use_mm2 = any(v is not None for v in changed_mm2)
    area = [np.nan if v is None else v for v in (changed_mm2 if use_mm2 else changed_px)]
    ax.bar(x, area, color="#c2185b", alpha=0.8)
    ax.set_ylabel("changed area (mm²)" if use_mm2 else "changed area (px)", fontsize=9)
    ax.set_xticks(x, dates, rotation=20, fontsize=7, ha="right")
    ax2 = ax.twinx()
    ax2.plot(x, [np.nan if v is None else v for v in afd_px], "o-", color="#1f5fa8")
    ax2.set_ylabel("AFD after relocation (px)", fontsize=9, color="#1f5fa8")
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return _figure_png(fig)


def region_closeup(ref_image: np.ndarray, cur_image: np.ndarray, labels: np.ndarray, region: ChangeRegion, *,
                   tile_px: int = 180) -> np.ndarray:
    """Before / after / outlined close-up of one region, side by side (HxWx3 uint8 RGB).

    The crop is square, centred on the region, its side 2x the region's larger
    extent (at least 40 px); it is enlarged to ``tile_px`` per tile so a 10 px change
    is seen. Tiles: reference, current (registered into the reference frame), and
    the reference with the region's outline. Nothing is drawn on the first two, so
    the change itself is not hidden.
    """
    h, w = labels.shape
    x, y, bw, bh = region.bbox_xywh
    side = int(max(40, 2 * max(bw, bh)))
    side = min(side, h, w)
    cx, cy = x + bw / 2.0, y + bh / 2.0
    x0 = int(np.clip(round(cx - side / 2), 0, w - side))
    y0 = int(np.clip(round(cy - side / 2), 0, h - side))
    window = (slice(y0, y0 + side), slice(x0, x0 + side))
    scale = tile_px / side
    interp = cv2.INTER_NEAREST if scale >= 3 else cv2.INTER_CUBIC
    tiles = []
    for image in (ref_image, cur_image, ref_image):
        tile = cv2.resize(to_display_rgb(image)[window], (tile_px, tile_px), interpolation=interp)
        tiles.append(np.ascontiguousarray(tile))
    inside = (labels[window] == region.id).astype(np.uint8)
    inside = cv2.resize(inside, (tile_px, tile_px), interpolation=cv2.INTER_NEAREST)
    contours, _ = cv2.findContours(inside, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(tiles[2], contours, -1, CHANGE_RGB, 2)
    gap = np.full((tile_px, 6, 3), 255, np.uint8)
    return np.hstack([tiles[0], gap, tiles[1], gap, tiles[2]])
