"""Figures of the change reports, as RGB arrays or PNG bytes (matplotlib Agg, OpenCV drawing)."""

from __future__ import annotations

import base64
from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.regions import ChangeRegion  # noqa: E402
from fgcd_cli.changes.significance import SignificantRegion  # noqa: E402
from fgcd_cli.report.charts import (  # noqa: E402, F401 - the charts, re-exported here
    CONVERGENCE_PANELS,
    ESTIMATE_STYLE,
    HISTORY_MIN_SLOTS,
    TRUTH_STYLE,
    convergence_figure,
    convergence_png,
    history_figure,
    history_png,
)
from fgcd_cli.report.charts import (
    figure_png as _figure_png,
)
from fgcd_cli.report.mpl import plt

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


def candidate_radius_px(area_px: float, shape: tuple[int, ...]) -> int:
    """Radius of a candidate's circle: 1.5x that of a disc of its area, at least 1 % of the image (5 px)."""
    return int(round(max(1.5 * np.sqrt(max(area_px, 0) / np.pi), min(shape[:2]) / 100, 5)))


def _dashed_circle(
    out: np.ndarray, centre: tuple[int, int], radius: int, colour: tuple[int, int, int], *, dashes: int = 16
) -> None:
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


def change_overlay(
    image: np.ndarray,
    labels: np.ndarray,
    regions: list[ChangeRegion],
    *,
    valid: np.ndarray | None = None,
    set_aside: np.ndarray | None = None,
    candidates: list[SignificantRegion] | None = None,
) -> np.ndarray:
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


@dataclass(frozen=True, kw_only=True)
class LegendEntry:
    """One entry of the overlay's legend: a swatch drawn the way the overlay draws it, and its meaning."""

    swatch: str
    """``fill`` (tinted and outlined region), ``outline`` (thin outline), ``dashed`` (dashed circle),
    ``dim`` (dimmed image) or ``number`` (a region's number)."""
    colour: tuple[int, int, int]
    text: str


def overlay_legend_entries(
    regions: list[ChangeRegion], *, set_aside: bool = False, candidates: bool = False, dimmed: bool = False
) -> list[LegendEntry]:
    """What :func:`change_overlay` drew, as legend entries (only what is on the image).

    Parameters
    ----------
    regions : list of ChangeRegion
        Reported regions; one entry per cue present (``CUE_RGB``), one for regions without a cue.
    set_aside : bool, keyword-only
        Regions set aside by the edge check are outlined (cyan).
    candidates : bool, keyword-only
        Candidates not reported are circled (dashed amber).
    dimmed : bool, keyword-only
        Part of the image was not compared (dimmed).
    """
    entries = []
    cues = {r.cue for r in regions}
    for cue, colour in CUE_RGB.items():
        if cue in cues:
            entries.append(LegendEntry(swatch="fill", colour=colour, text=f"changed: {cue}"))
    if any(r.cue not in CUE_RGB for r in regions):
        entries.append(
            LegendEntry(swatch="fill", colour=CHANGE_RGB, text="changed" if len(entries) == 0 else "changed: no cue")
        )
    if regions:
        entries.append(LegendEntry(swatch="number", colour=LABEL_RGB, text="region number"))
    if set_aside:
        entries.append(LegendEntry(swatch="outline", colour=SET_ASIDE_RGB, text="set aside (edge)"))
    if candidates:
        entries.append(LegendEntry(swatch="dashed", colour=CANDIDATE_RGB, text="candidate, not reported"))
    if dimmed:
        entries.append(LegendEntry(swatch="dim", colour=(90, 90, 90), text="not compared"))
    if not entries:
        entries.append(LegendEntry(swatch="outline", colour=(150, 150, 150), text="no change reported"))
    return entries


LEGEND_STONE_RGB = (120, 120, 120)
"""Background of the legend's swatches: a mid grey, like the stone the overlay is drawn on."""


def _draw_swatch(band: np.ndarray, entry: LegendEntry, x: int, y: int, side: int) -> None:
    """The swatch of ``entry`` in the square of side ``side`` at (x, y) (top-left), in place."""
    box = (slice(y, y + side), slice(x, x + side))
    stone = np.array(LEGEND_STONE_RGB, np.float32)
    if entry.swatch == "fill":
        band[box] = (0.55 * stone + 0.45 * np.array(entry.colour)).astype(np.uint8)
        cv2.rectangle(band, (x, y), (x + side - 1, y + side - 1), entry.colour, 2)
    elif entry.swatch == "outline":
        band[box] = LEGEND_STONE_RGB
        cv2.rectangle(band, (x + 1, y + 1), (x + side - 2, y + side - 2), entry.colour, 1)
    elif entry.swatch == "dashed":
        band[box] = LEGEND_STONE_RGB
        _dashed_circle(band, (x + side // 2, y + side // 2), max(3, side // 2 - 2), entry.colour, dashes=5)
    elif entry.swatch == "dim":
        band[box] = (stone * 0.35).astype(np.uint8)
    else:  # number
        band[box] = (60, 60, 60)
        scale = side / 30
        cv2.putText(
            band,
            "1",
            (x + side // 4, y + side - side // 6),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            entry.colour,
            2,
            cv2.LINE_AA,
        )


def with_legend(overlay: np.ndarray, entries: list[LegendEntry]) -> np.ndarray:
    """``overlay`` with a legend band appended below it (the image's own pixels are untouched).

    The band is white, its entries (swatch + text) laid out left to right and wrapped
    onto further rows when the image is narrow; type scales with the image width.

    Returns
    -------
    ndarray, (H + band) x W x 3 uint8 RGB; rows ``0..H-1`` are ``overlay`` itself.
    """
    w = overlay.shape[1]
    scale = max(0.4, w / 1600)
    side = int(round(22 * scale / 0.6))
    gap = side // 2
    sizes = [cv2.getTextSize(e.text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] + side + 2 * gap for e in entries]
    rows, row, used = [], [], gap
    for entry, size in zip(entries, sizes):
        if row and used + size > w:
            rows.append(row)
            row, used = [], gap
        row.append((entry, used))
        used += size
    rows.append(row)
    row_h = side + gap
    band = np.full((gap + len(rows) * row_h, w, 3), 255, np.uint8)
    for r, items in enumerate(rows):
        y = gap + r * row_h
        for entry, x in items:
            _draw_swatch(band, entry, x, y, side)
            cv2.putText(
                band,
                entry.text,
                (x + side + gap // 2, y + side - side // 4),
                cv2.FONT_HERSHEY_SIMPLEX,
                scale,
                (40, 40, 40),
                1,
                cv2.LINE_AA,
            )
    return np.vstack([overlay, band])


def score_heatmap(score: np.ndarray, valid: np.ndarray, *, high: float | None = None) -> np.ndarray:
    """Change score as an RGB heat map (magma), saturating at ``high`` (default: 99.9th percentile)."""
    values = score[valid] if valid.any() else score.ravel()
    top = high if high is not None and high > 0 else float(np.percentile(values, 99.9)) or 1.0
    normalized = np.clip(score / top, 0.0, 1.0)
    rgb = (plt.get_cmap("magma")(normalized)[:, :, :3] * 255).astype(np.uint8)
    rgb[~valid] = (40, 40, 40)
    return rgb


FDF_ARROW_FRACTION = 0.04
"""A displacement of the 3 px success limit (or the field's median, if larger) is drawn this share of the image width."""
FDF_SCALE_FLOOR_PX = 3.0
"""Fields whose median is below this (rACR's success limit) keep the magnification of a field of this size, so a
0.2 px field is drawn small and calm (its noise is not blown up into chaos)."""


def fdf_magnification(median_px: float, width_px: int) -> float:
    """How many times the FDF arrows are magnified on the figure.

    Parameters
    ----------
    median_px : float
        Median displacement length of the field (px).
    width_px : int
        Image width (px).

    Returns
    -------
    float
        A whole number >= 1: ``FDF_ARROW_FRACTION * width / max(median, FDF_SCALE_FLOOR_PX)``, so the
        median arrow is at most ~4 % of the width and a field below the success limit looks as small
        as it is.
    """
    reference = max(float(median_px) if np.isfinite(median_px) else 0.0, FDF_SCALE_FLOOR_PX)
    return float(max(1.0, round(FDF_ARROW_FRACTION * width_px / reference)))


def fdf_quiver_png(
    ref_image: np.ndarray,
    points_ref: np.ndarray,
    points_cur: np.ndarray,
    *,
    afd_px: float,
    inliers: int,
    method: str,
    max_arrows: int = 400,
) -> bytes:
    """FDF quiver figure: displacement vectors drawn on the reference image, AFD in the title.

    Arrows are magnified (:func:`fdf_magnification`); the magnification is stated in the
    title and by a key arrow of the 3 px success limit drawn at that scale (lower left corner).
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
    magnify = fdf_magnification(median, w)
    fig, ax = plt.subplots(figsize=(6.4, 6.4 * h / w))
    ax.imshow(rgb, cmap="gray")
    if len(pts):
        arrows = ax.quiver(
            pts[:, 0],
            pts[:, 1],
            disp[:, 0] * magnify,
            disp[:, 1] * magnify,
            angles="xy",
            scale_units="xy",
            scale=1,
            color="#ffd400",
            width=0.004,
            headwidth=4,
        )
        # the key: an arrow of the success limit at the drawing's scale, in the image's lower left corner
        key = ax.quiverkey(
            arrows,
            0.05,
            0.05,
            FDF_SCALE_FLOOR_PX * magnify,
            f"{FDF_SCALE_FLOOR_PX:g} px (success limit)",
            labelpos="E",
            coordinates="axes",
            labelcolor="white",
            fontproperties={"size": 8, "weight": "bold"},
        )
        key.set_zorder(5)
    ax.set_title(
        f"FDF ({method}): AFD = {afd_px:.2f} px, {inliers} vectors\narrows drawn x{magnify:g} (median {median:.2f} px)",
        fontsize=10,
    )
    ax.set_axis_off()
    return _figure_png(fig)


def region_closeup(
    ref_image: np.ndarray, cur_image: np.ndarray, labels: np.ndarray, region: ChangeRegion, *, tile_px: int = 180
) -> np.ndarray:
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


def result_overlay(image: np.ndarray, result, *, legend: bool = True) -> np.ndarray:
    """The change map of a comparison as the reports show it: :func:`change_overlay` of its regions,
    set-aside regions, candidates and compared area, with the legend of what is drawn appended below.

    Parameters
    ----------
    image : ndarray, the reference image shown (one lighting).
    result : ChangeResult, the comparison.
    legend : bool, keyword-only; append the legend band (:func:`with_legend`).
    """
    valid = result.valid if result.comparable else None
    overlay = change_overlay(
        image, result.labels, result.regions, valid=valid, set_aside=result.edge_explained, candidates=result.candidates
    )
    if not legend:
        return overlay
    entries = overlay_legend_entries(
        result.regions,
        set_aside=result.edge_explained is not None and bool(result.edge_explained.any()),
        candidates=bool(result.candidates),
        dimmed=valid is not None and not bool(valid.all()),
    )
    return with_legend(overlay, entries)
