"""The diff report (``report.html``): one comparison as self-contained HTML (images embedded as base64 PNG).

:class:`ReportContext` is what the report shows beside the comparison; :func:`render_diff_report`
writes the page: the verdict, the images, where it changed (map, regions, close-ups,
candidates), the camera relocation and the capture and processing details. The blocks
every page shares are in :mod:`fgcd_cli.report.html_page`; the station history is
:mod:`fgcd_cli.report.station_history`.
"""

from __future__ import annotations

import html
from dataclasses import dataclass

import numpy as np

from fgcd_cli.changes.config import RegionConfig
from fgcd_cli.changes.regions import by_evidence
from fgcd_cli.changes.result import ChangeResult
from fgcd_cli.metrics.afd import FdfResult
from fgcd_cli.report.areas import area_mm2_text
from fgcd_cli.report.candidates import (
    candidate_dict,
    candidate_text,
    clipped_text,
    contrast_text,
    faint_text,
    is_significant,
    nfa_text,
    p_text,
    region_significance_text,
    set_aside_text,
    settings_epsilon,
    tone_text,
)
from fgcd_cli.report.charts import convergence_png
from fgcd_cli.report.figures import (
    CUE_NAMES,
    fdf_quiver_png,
    png_bytes,
    region_closeup,
    result_overlay,
    score_heatmap,
    to_display_rgb,
)
from fgcd_cli.report.html_page import _figure, _img, _page
from fgcd_cli.report.pose_check import relocation_check_text
from fgcd_cli.report.scene_map import scene_uncertainty_section


def _plain(value) -> str:
    """A metadata value as readable text: lists of files as folder + names, dicts as ``key: value`` lines."""
    if isinstance(value, dict):
        return "; ".join(f"{html.escape(str(k))} = {_plain(v)}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        items = [str(v) for v in value]
        if len(items) > 1 and all("/" in v for v in items):
            folders = {v.rsplit("/", 1)[0] for v in items}
            if len(folders) == 1:
                return f"{html.escape(folders.pop())}/: " + ", ".join(html.escape(v.rsplit("/", 1)[1]) for v in items)
        return ", ".join(html.escape(v) for v in items)
    if isinstance(value, float):
        return f"{value:.4g}" if np.isfinite(value) else "–"
    return html.escape(str(value))


def _kv_table(items: dict) -> str:
    rows = [f"<tr><td>{html.escape(str(key))}</td><td>{_plain(value)}</td></tr>" for key, value in items.items()]
    return f'<table class="kv">{"".join(rows)}</table>'


def _epsilon(result: ChangeResult) -> float:
    return settings_epsilon(result.settings)


def _no_change_verdict(result: ChangeResult) -> str:
    """Verdict without reported region: "No significant change", naming the strongest candidate."""
    surface = f"on the compared surface ({result.valid.mean() * 100:.0f} % of the image)"
    epsilon = _epsilon(result)
    if not result.candidates:
        return f'<div class="verdict none"><b>No significant change</b> {surface}; no candidate region either.</div>'
    strongest = candidate_dict(result.candidates[0])
    where = html.escape(candidate_text(strongest))
    if is_significant(strongest["log10_nfa"], epsilon=epsilon):
        rule = html.escape(str(result.settings.get("decision") or "threshold"))
        return (
            f'<div class="verdict"><b>No change reported</b> {surface} by the {rule} rule, but the strongest '
            f"candidate is significant: <b>{where}</b>. Check it by eye (dashed amber circle c1 on the change "
            "map).</div>"
        )
    times = nfa_text(strongest["log10_nfa"])
    return (
        f'<div class="verdict none"><b>No significant change</b> {surface}. '
        f'<span class="cand">Strongest candidate: <b>{where}</b>. A region this strong is expected about '
        f"{times} time(s) per image on an unchanged pair (NFA ≥ {epsilon:g}), so it is not reported; "
        "it is circled faintly (dashed amber, c1) on the change map.</span></div>"
    )


def _verdict(result: ChangeResult) -> str:
    return _verdict_body(result).replace("</div>", _set_aside_banner(result) + "</div>", 1)


def _set_aside_banner(result: ChangeResult) -> str:
    """The verdict's note on regions the edge check set aside: they stay candidates, never silently gone."""
    n = int(result.settings.get("edge_explained_regions") or 0) if result.comparable else 0
    if n == 0:
        return ""
    return (
        f' <span class="cand"><b>{len(result.regions)} change{"s" if len(result.regions) != 1 else ""}'
        f"{html.escape(set_aside_text(n))}</b> (cyan outlines on the change map): a sub-pixel difference of "
        "viewpoint may explain it; check by eye.</span>"
    )


def _verdict_body(result: ChangeResult) -> str:
    if not result.comparable:
        reason = result.reason.removeprefix("cannot compare: ")
        return (
            f'<div class="verdict cannot"><b>Not compared:</b> {html.escape(reason)}. '
            "No change map was made; check the capture (exposure, lighting, framing) and compare again.</div>"
        )
    n = len(result.regions)
    if n == 0:
        return _no_change_verdict(result)
    total_px = sum(r.area_px for r in result.regions)
    mm2 = [r.area_mm2 for r in result.regions]
    area = (
        f"{area_mm2_text(sum(mm2), total_px)} ({total_px} px)"
        if all(v is not None for v in mm2)
        else f"{total_px} px (no metric scale given)"
    )
    top = by_evidence(result.regions)[0]
    high = result.detection_level or 1.0
    where = f"at ({top.centroid_xy[0]:.0f}, {top.centroid_xy[1]:.0f})"
    size = area_mm2_text(top.area_mm2, top.area_px) if top.area_mm2 is not None else f"{top.area_px} px"
    return (
        f'<div class="verdict"><b>{n} changed region{"s" if n > 1 else ""}</b>, total area {area}, '
        f"{result.changed_fraction * 100:.2f} % of the compared surface. Strongest: region {top.id}, "
        f"{top.max_score / high:.1f} × the detection level, {size} {where}; the table and the close-ups "
        "list the regions strongest first.</div>"
    )


def _candidates_table(result: ChangeResult) -> str:
    """The strongest regions that were not reported, as a table (most significant first)."""
    high = result.detection_level
    rows = []
    for k, candidate in enumerate(result.candidates, start=1):
        x, y = candidate.centroid_xy
        strength = f"{candidate.peak_score / high:.1f}" if high else "–"
        rows.append(
            f"<tr><td>c{k}</td><td>{nfa_text(candidate.log10_nfa)}</td><td>{p_text(candidate.p_level)}</td>"
            f"<td>{x:.0f}, {y:.0f}</td><td>{candidate.area_px}</td><td>{strength}</td>"
            f'<td class="l">{html.escape(candidate.why)}</td></tr>'
        )
    return (
        "<h2>Candidates not reported</h2><table><tr><th>#</th><th>significance (NFA)</th><th>level p</th>"
        '<th>centre x, y (px)</th><th>area (px)</th><th>strength (× threshold)</th><th class="l">why not reported</th></tr>'
        + "".join(rows)
        + '</table><p class="small">The strongest regions of the change score that were not reported (dashed '
        "amber circles on the change map): first those fainter than the contrast floor or explained by clipped "
        "highlights, strongest first, then the "
        "others, most significant first. NFA: regions at least as extreme expected "
        f"per image on an unchanged pair (reported below {_epsilon(result):g}); level p: the share of compared "
        "pixels scoring at least the level at which the region was found; area: pixels at that level.</p>"
    )


def _convergence_caption(relocation_log: list[dict]) -> str:
    """Caption of the convergence figure: what its lines are, truth named only when it is plotted."""
    caption = (
        "Convergence of the relocation, per adjustment (as rACR Fig. 8): solid blue, the tool's own "
        "estimates of what remained"
    )
    if any(key.endswith("_true") for row in relocation_log for key in row):
        caption += "; dashed grey, the simulator's truth (evaluation only, never seen by the tool)"
    return caption


@dataclass(frozen=True, kw_only=True)
class ReportContext:
    """What a diff report shows beside the comparison itself.

    Attributes
    ----------
    relocation_log : list of dict or None
        One row per relocation adjustment (the convergence figure).
    metadata : dict or None
        Capture metadata shown as a table.
    title, subtitle : str
        The page's heading.
    max_table_rows : int
        Regions listed in the table (all of them are in regions.json).
    max_closeups : int
        Regions enlarged (0: no close-ups).
    scene_map : SceneUncertaintyMap or None
        The reference's scene uncertainty map (its figure, with the coarse stage's estimates).
    coarse_log : list of dict or None
        The visit's ``coarse.jsonl`` rows.
    """

    relocation_log: list[dict] | None = None
    metadata: dict | None = None
    title: str = "Change report"
    subtitle: str = ""
    max_table_rows: int = 50
    max_closeups: int = 12
    scene_map: object | None = None
    coarse_log: list[dict] | None = None


def render_diff_report(
    *,
    ref_image: np.ndarray,
    cur_image: np.ndarray,
    result: ChangeResult,
    cur_registered: np.ndarray | None = None,
    fdf: FdfResult | None = None,
    context: ReportContext | None = None,
) -> str:
    """HTML text of the report of one comparison (reference vs current observation).

    Parameters
    ----------
    ref_image : ndarray, the reference image shown (one lighting), reference frame.
    cur_image : ndarray, the current image as captured (same lighting).
    cur_registered : ndarray, optional; the current image registered and light-normalized
        into the reference frame, shown instead of ``cur_image`` when given.
    result : ChangeResult from :func:`fgcd_cli.changes.detect_changes`.
    fdf : FdfResult, optional; the FDF quiver and AFD of this pair.
    context : ReportContext, optional; relocation log, metadata, title and limits.
    """
    ctx = context if context is not None else ReportContext()
    shown_cur = cur_registered if cur_registered is not None else cur_image
    parts = _summary_section(result, fdf, ctx)
    parts += _images_section(ref_image, shown_cur, registered=cur_registered is not None)
    if result.comparable:
        parts += _changes_section(ref_image, shown_cur, result, ctx)
    if fdf is not None or ctx.relocation_log or ctx.scene_map is not None:
        parts += _relocation_section(ref_image, fdf, ctx.relocation_log)
        parts += scene_uncertainty_section(ctx.scene_map, ctx.coarse_log)
    parts.append("<h2>Capture and processing details</h2>" + _kv_table(_details(result, fdf, ctx.metadata)))
    return _page(ctx.title, "".join(parts))


def _summary_section(result: ChangeResult, fdf: FdfResult | None, ctx: ReportContext) -> list[str]:
    """Title, verdict, warnings, the regions set aside and the camera return (AFD)."""
    parts = [f"<h1>{html.escape(ctx.title)}</h1>"]
    if ctx.subtitle:
        parts.append(f'<div class="sub">{html.escape(ctx.subtitle)}</div>')
    parts.append(_verdict(result))
    for warning in result.warnings:
        parts.append(f'<div class="warn">⚠ {html.escape(warning)}</div>')
    set_aside = int(result.settings.get("edge_explained_regions") or 0)
    if set_aside:
        parts.append(
            f"<p>{set_aside} further region{'s' if set_aside > 1 else ''} along strong edges of the reference "
            f"{'were' if set_aside > 1 else 'was'} set aside: a sub-pixel difference of viewpoint explains "
            f"{'them' if set_aside > 1 else 'it'} (thin lines and edges thinned or moved by up to 2 px). "
            "They are outlined in cyan on the change map; check them by eye where an edge itself may have changed.</p>"
        )
    faint = faint_text(result.settings)
    if faint:
        parts.append(f"<p>{html.escape(faint)}: too faint for a surface change a revisit can vouch for.</p>")
    clipped = clipped_text(result.settings)
    if clipped:
        parts.append(
            f"<p>{html.escape(clipped)}: a clipped pixel records no brightness, and a glossy highlight slides "
            "over the surface when the camera moves by a millimetre.</p>"
        )
    if fdf is not None:
        quality = "within" if fdf.afd_px < 3 else "outside"
        parts.append(
            f"<p>Camera return: AFD = <b>{fdf.afd_px:.2f} px</b> ({fdf.method}, {fdf.inliers} vectors), "
            f"{quality} the 3 px success limit of the rACR paper. Residual motion is compensated before comparing.</p>"
        )
    geo = result.settings.get("geometry") or {}
    if "residual_pose_mm" in geo:
        stated = ((ctx.metadata or {}).get("relocation") or {}).get("residual")
        check = relocation_check_text(stated, result.settings)
        parts.append(
            f"<p>Camera position, measured against the reference's depth: <b>{geo['residual_pose_mm']:.2f} mm</b>, "
            f"{geo['residual_pose_deg']:.3f}° from the reference"
            + (f"; {html.escape(check.split(': ', 1)[1])}" if check else "")
            + ".</p>"
        )
    return parts


def _images_section(ref_image: np.ndarray, shown_cur: np.ndarray, *, registered: bool) -> list[str]:
    """The reference and current images side by side."""
    cur_caption = (
        "Current observation, registered onto the reference and light-normalized"
        if registered
        else "Current observation as captured (not registered)"
    )
    return [
        '<h2>Reference and current images</h2><div class="pair">',
        _figure(png_bytes(to_display_rgb(ref_image)), "Reference observation"),
        _figure(png_bytes(to_display_rgb(shown_cur)), cur_caption),
        "</div>",
    ]


def _changes_section(
    ref_image: np.ndarray, shown_cur: np.ndarray, result: ChangeResult, ctx: ReportContext
) -> list[str]:
    """Where it changed: the change map and score, the regions table, close-ups, candidates."""
    set_aside = int(result.settings.get("edge_explained_regions") or 0)
    parts = ['<h2>Where it changed</h2><div class="pair">']
    overlay = result_overlay(ref_image, result)
    cues = sorted({r.cue for r in result.regions if r.cue in CUE_NAMES}, key=list(CUE_NAMES).index)
    tint = (
        (
            "tinted by cue: "
            + ", ".join(f"{CUE_NAMES[c]} = {c}" for c in cues)
            + (", magenta = no cue" if any(r.cue is None for r in result.regions) else "")
        )
        if cues
        else "magenta"
    )
    parts.append(
        _figure(
            png_bytes(overlay),
            f"Changed regions ({tint}; numbered) on the reference; "
            + ("cyan outline = set aside as an edge effect; " if set_aside else "")
            + ("dashed amber circles c1, c2, … = strongest candidates, not reported; " if result.candidates else "")
            + "dimmed = not compared",
        )
    )
    parts.append(
        _figure(
            png_bytes(score_heatmap(result.score, result.valid, high=result.detection_level)),
            "Change score (bright = strong difference; saturates at the detection threshold)",
        )
    )
    parts.append("</div>")
    if result.regions:
        parts += _regions_table(result, ctx.max_table_rows)
        if ctx.max_closeups > 0:
            parts += _closeups(ref_image, shown_cur, result, ctx.max_closeups)
    if result.candidates:
        parts.append(_candidates_table(result))
    return parts


def _regions_table(result: ChangeResult, max_rows: int) -> list[str]:
    """The changed regions as a table (strongest first, :func:`by_evidence`), with what its columns mean."""
    has_mm2 = any(r.area_mm2 is not None for r in result.regions)
    header = (
        "<tr><th>#</th><th>area (px)</th>"
        + ("<th>area (mm²)</th>" if has_mm2 else "")
        + "<th>centre x, y (px)</th><th>size w × h (px)</th><th>strength (× threshold)</th>"
        '<th>significance (NFA)</th><th class="l">contrast (seen under)</th><th class="l">cue</th>'
        '<th class="l">now</th></tr>'
    )
    n_lightings = int(result.settings.get("lightings") or 0) or None
    epsilon = _epsilon(result)
    rows = []
    high = result.detection_level or 1.0
    for r in by_evidence(result.regions)[:max_rows]:
        x, y, w, h = r.bbox_xywh
        rows.append(
            f"<tr><td>{r.id}</td><td>{r.area_px}</td>"
            + (f"<td>{area_mm2_text(r.area_mm2, r.area_px, unit=False)}</td>" if has_mm2 else "")
            + f"<td>{r.centroid_xy[0]:.0f}, {r.centroid_xy[1]:.0f}</td><td>{w} × {h}</td>"
            f"<td>{r.max_score / high:.1f}</td>"
            f"<td>{html.escape(region_significance_text(r.log10_nfa, epsilon=epsilon).removeprefix('NFA '))}</td>"
            f'<td class="l">{html.escape(contrast_text(r.contrast, r.lightings, n_lightings) or "–")}</td>'
            f'<td class="l">{html.escape(r.cue or "–")}</td>'
            f'<td class="l">{html.escape(tone_text(r.tone, r.brightness_change) or "–")}</td></tr>'
        )
    more = len(result.regions) - max_rows
    parts = [f"<h2>Changed regions</h2><table>{header}{''.join(rows)}</table>"]
    if more > 0:
        parts.append(f'<p class="small">… and {more} weaker regions (all in regions.json).</p>')
    parts.append(
        '<p class="small">Positions are pixels of the reference image (x to the right, y down). '
        "Strength: the region's largest change score over the level at which the decision starts a "
        f"region (a-contrario: the pair's top {100 * float(result.settings.get('seed_p', RegionConfig().seed_p)):g} % of scores; "
        "a region also needs its significance, so a weak but extended one may be below 1; "
        "hysteresis: its high threshold). Significance: the number of false alarms (NFA), how many regions "
        "at least as extreme are expected per image on an unchanged pair (a-contrario; "
        f"below {epsilon:g} = significant). Contrast: the change at its strongest, relative to the "
        "surface's brightness, and the lightings (numbered as listed) where it is at least half that; "
        "regions below the contrast floor are not reported. Cue: what changed, relief (surface normals) or colour "
        "(albedo) or both, when the photometric cues were computed. Now: darker or brighter than at the "
        "reference (the region's light over every lighting), or mixed when the lightings disagree "
        "(relief shades one way under one light, the other way under another).</p>"
    )
    return parts


def _closeups(ref_image: np.ndarray, shown_cur: np.ndarray, result: ChangeResult, max_closeups: int) -> list[str]:
    """Each of the strongest regions enlarged: reference | current | reference with the region outlined."""
    high = result.detection_level or 1.0
    parts = [
        '<h2>Close-ups</h2><p class="small">Each region enlarged: reference | current '
        "(registered, light-normalized) | reference with the region outlined.</p>"
        '<div class="closeups">'
    ]
    for r in by_evidence(result.regions)[:max_closeups]:
        area = area_mm2_text(r.area_mm2, r.area_px) if r.area_mm2 is not None else f"{r.area_px} px"
        tile = region_closeup(ref_image, shown_cur, result.labels, r)
        extra = (f", NFA {nfa_text(r.log10_nfa)}" if r.log10_nfa is not None else "") + (f", {r.cue}" if r.cue else "")
        tone = tone_text(r.tone, r.brightness_change)
        extra += f", {tone}" if tone else ""
        parts.append(_figure(png_bytes(tile), f"Region {r.id}: {area}, strength {r.max_score / high:.1f}{extra}"))
    parts.append("</div>")
    if len(result.regions) > max_closeups:
        parts.append(f'<p class="small">Close-ups of the {max_closeups} strongest regions only.</p>')
    return parts


def _relocation_section(ref_image: np.ndarray, fdf: FdfResult | None, relocation_log: list[dict] | None) -> list[str]:
    """Camera relocation: the FDF quiver and the convergence of the relocation log."""
    parts = ['<h2>Camera relocation</h2><div class="pair">']
    if fdf is not None:
        parts.append(
            _figure(
                fdf_quiver_png(
                    ref_image, fdf.points_ref, fdf.points_cur, afd_px=fdf.afd_px, inliers=fdf.inliers, method=fdf.method
                ),
                "Feature displacement field from reference to current image (before registration)",
            )
        )
    parts.append("</div>")
    if relocation_log:
        # Full width: three panels side by side are unreadable at half the page.
        try:
            parts.append(
                '<div class="pair"><figure class="wide">'
                + _img(convergence_png(relocation_log), "relocation convergence")
                + f"<figcaption>{html.escape(_convergence_caption(relocation_log))}</figcaption></figure></div>"
            )
        except ValueError as exc:  # a log without any plottable column
            parts.append(f'<p class="small">Relocation log not plotted: {html.escape(str(exc))}.</p>')
    return parts


def _details(result: ChangeResult, fdf: FdfResult | None, metadata: dict | None) -> dict:
    """Capture and processing details: the metadata, registration, threshold and settings."""
    details = {}
    if metadata:
        details.update(metadata)
    if result.registration is not None:
        reg = result.registration
        details["registration"] = {
            "init": reg.init,
            "sift_inliers": reg.sift_inliers,
            "ecc_correlation": round(reg.ecc_correlation, 4) if np.isfinite(reg.ecc_correlation) else None,
            "overlap": round(reg.overlap_fraction, 3),
        }
    if result.threshold is not None:
        t = result.threshold
        details["threshold"] = {
            "decision": result.settings.get("decision"),
            "detection_level": round(result.detection_level, 3),
            "reference rule": t.method,
            "k_high": t.k_high,
            "k_low": t.k_low,
            "high": round(t.high, 3),
            "low": round(t.low, 3),
            "median": round(t.median, 3),
            "sigma_upper": round(t.sigma_upper, 4),
        }
    details["settings"] = result.settings
    if fdf is not None:
        details["afd settings"] = fdf.settings
    return details
