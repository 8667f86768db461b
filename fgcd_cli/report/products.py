"""The files of one comparison (change maps, regions, report) as bytes, ready to write anywhere."""

from __future__ import annotations

import io
import json
from dataclasses import asdict

import numpy as np

from fgcd_cli.campaign import schema
from fgcd_cli.changes.result import ChangeResult
from fgcd_cli.metrics.afd import FdfResult
from fgcd_cli.report.candidates import candidate_dict, nfa_value
from fgcd_cli.report.figures import fdf_quiver_png, png_bytes, result_overlay
from fgcd_cli.report.html import ReportContext, render_diff_report

SCORE_PNG_FULL_SCALE = 4.0
"""``change_score.png`` maps score 0..(4 x detection threshold) to 0..65535 (recorded in regions.json)."""


def result_summary(result: ChangeResult, fdf: FdfResult | None = None) -> dict:
    """JSON-ready summary of a comparison (what ``regions.json`` holds).

    Each region carries its ``log10_nfa`` and ``nfa`` (a-contrario number of false
    alarms; None when the region holds no significant seed) and its ``cue``;
    ``candidates`` lists the strongest regions that were not reported, most
    significant first, each with ``log10_nfa``, ``nfa``, ``p_level``, ``area_px``,
    ``centroid_xy`` and ``peak_score``, so that "no change" is never silent.
    """
    reg = result.registration
    summary = {
        "comparable": result.comparable,
        "reason": result.reason,
        "frame": "reference image pixels (x right, y down)",
        "changed_fraction": result.changed_fraction,
        "compared_fraction": float(result.valid.mean()),
        # strength: the region's peak score over the level at which the decision starts a region
        "regions": [
            {**asdict(r), "nfa": nfa_value(r.log10_nfa), "strength": result.strength(r)} for r in result.regions
        ],
        "candidates": [candidate_dict(c) for c in result.candidates],
        "registration": None
        if reg is None
        else {
            "H_cur_ref": reg.H_cur_ref.tolist(),
            "ok": reg.ok,
            "reason": reg.reason,
            "init": reg.init,
            "sift_inliers": reg.sift_inliers,
            "ecc_correlation": reg.ecc_correlation,
            "overlap_fraction": reg.overlap_fraction,
            "settings": reg.settings,
        },
        "threshold": None if result.threshold is None else asdict(result.threshold),
        "settings": result.settings,
        "warnings": result.warnings,
        "set_aside_px": 0 if result.edge_explained is None else int(result.edge_explained.sum()),
    }
    if result.threshold is not None:
        summary["change_score_png_scale"] = {
            "full_scale_score": SCORE_PNG_FULL_SCALE * result.threshold.high,
            "note": "change_score.png value v means score v / 65535 * full_scale_score",
        }
    if fdf is not None:
        summary["afd"] = fdf.as_dict()
    return summary


def diff_products(
    *,
    ref_images: list[np.ndarray],
    cur_images: list[np.ndarray],
    result: ChangeResult,
    fdf: FdfResult | None = None,
    context: ReportContext | None = None,
    shown_lighting: int = 0,
) -> dict[str, bytes]:
    """All output files of a comparison, by file name.

    Returns a dict with ``change_score.png`` (16-bit), ``change_score.npy`` (float32),
    ``change_mask.png`` (0/255), ``overlay.png`` (the change map, its legend in a band
    below the image), ``regions.json``, ``report.html``
    and, when ``fdf`` is given, ``fdf.png``. ``context`` (relocation log, metadata, title,
    subtitle; :class:`fgcd_cli.report.html.ReportContext`) defaults to an empty one.
    """
    ctx = context if context is not None else ReportContext()
    metadata = ctx.metadata
    files: dict[str, bytes] = {}
    summary = result_summary(result, fdf)
    if metadata:
        summary["metadata"] = metadata
    full_scale = SCORE_PNG_FULL_SCALE * result.threshold.high if result.threshold else 1.0
    score16 = np.clip(result.score / full_scale * 65535.0 + 0.5, 0, 65535).astype(np.uint16)
    files[schema.CHANGE_SCORE_PNG] = png_bytes(score16)
    buffer = io.BytesIO()
    np.save(buffer, result.score.astype(np.float32))
    files[schema.CHANGE_SCORE_NPY] = buffer.getvalue()
    files[schema.CHANGE_MASK_PNG] = png_bytes((result.mask * 255).astype(np.uint8))
    ref_shown = ref_images[shown_lighting]
    # The change map with its legend below it: rows 0..H-1 are pixel-aligned with the reference image.
    files[schema.OVERLAY_PNG] = png_bytes(result_overlay(ref_shown, result))
    files[schema.REGIONS_JSON] = json.dumps(summary, indent=1, default=float).encode()
    if fdf is not None:
        files[schema.FDF_PNG] = fdf_quiver_png(
            ref_shown, fdf.points_ref, fdf.points_cur, afd_px=fdf.afd_px, inliers=fdf.inliers, method=fdf.method
        )
    files[schema.REPORT_HTML] = render_diff_report(
        ref_image=ref_shown,
        cur_image=cur_images[shown_lighting],
        result=result,
        fdf=fdf,
        cur_registered=result.current_registered[shown_lighting] if result.current_registered else None,
        context=ctx,
    ).encode()
    return files
