"""Report figures say what they show: the tool's own estimates (truth only labelled as simulator truth),
whole-number adjustments, a readable one-visit history, a legend on the change map, calm FDF arrows,
and areas to the precision of the pixels."""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from changes.conftest import textured_scene, translate  # noqa: E402

from fgcd_cli.app.visit_logs import relocation_log_rows  # noqa: E402
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.regions import ChangeRegion  # noqa: E402
from fgcd_cli.report.areas import area_mm2_text, round_area_mm2  # noqa: E402
from fgcd_cli.report.charts import convergence_figure, history_figure
from fgcd_cli.report.figures import (
    CANDIDATE_RGB,
    SET_ASIDE_RGB,
    change_overlay,
    fdf_magnification,
    overlay_legend_entries,
)
from fgcd_cli.report.html import ReportContext  # noqa: E402
from fgcd_cli.report.products import diff_products  # noqa: E402

ESTIMATES = {
    "afd_est_px": [30.0, 2.0, 0.5, 0.2],
    "offset_mm": [25.0, 3.0, 0.4, 0.1],
    "offset_deg": [2.5, 0.3, 0.05, 0.01],
}
TRUTH = {
    "afd_px": [32.0, 1.0, 0.8, 0.07],
    "pose_err_mm": [25.2, 5.3, 2.9, 0.2],
    "pose_err_deg": [2.5, 0.12, 0.1, 0.007],
}


class _Visit:
    """A visit holding only a relocation log, as the store serves it."""

    def __init__(self, rows):
        self._data = "\n".join(json.dumps(r) for r in rows).encode()

    def has(self, name):
        return name == "relocation.jsonl"

    def bytes(self, name):
        return self._data


def _logged_rows(*, with_truth: bool) -> list[dict]:
    rows = []
    for i in range(4):
        row = {"iteration": i + 1, "stage": "fine", **{k: v[i] for k, v in ESTIMATES.items()}}
        if with_truth:
            row["truth"] = {k: v[i] for k, v in TRUTH.items()}
        rows.append(row)
    return rows


def _lines(ax) -> dict[str, np.ndarray]:
    return {line.get_label(): np.asarray(line.get_ydata(), float) for line in ax.get_lines()}


def test_convergence_plots_the_tools_estimates_and_labels_truth_as_simulator_truth():
    fig = convergence_figure(relocation_log_rows(_Visit(_logged_rows(with_truth=True))))
    axes = fig.axes
    assert len(axes) == 3
    for ax, (est_key, true_key) in zip(
        axes, [("afd_est_px", "afd_px"), ("offset_mm", "pose_err_mm"), ("offset_deg", "pose_err_deg")]
    ):
        lines = _lines(ax)
        estimate = next(v for k, v in lines.items() if k.startswith("estimate"))
        np.testing.assert_allclose(estimate, ESTIMATES[est_key])
        np.testing.assert_allclose(lines["simulator truth"], TRUTH[true_key])
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        assert "simulator truth" in labels


def test_convergence_without_truth_has_no_truth_line():
    fig = convergence_figure(relocation_log_rows(_Visit(_logged_rows(with_truth=False))))
    for ax in fig.axes:
        assert "simulator truth" not in _lines(ax)
        assert "truth" not in ax.get_ylabel()


def test_convergence_ticks_are_whole_adjustments():
    rows = [{"iteration": i + 1, "offset_mm": 10.0 / (i + 1)} for i in range(3)]
    fig = convergence_figure(rows)
    fig.canvas.draw()
    ticks = fig.axes[0].get_xticks()
    lo, hi = fig.axes[0].get_xlim()
    shown = ticks[(ticks >= lo) & (ticks <= hi)]
    assert len(shown) >= 2 and np.allclose(shown, np.round(shown))


@pytest.mark.parametrize("area", [0.0, 975.97])
def test_one_visit_history_has_sensible_axes(area):
    fig = history_figure(["2025-06-01 00:00 UTC"], [area], [195 if area else 0], [0.42])
    ax, ax_afd = fig.axes
    lo, hi = ax.get_xlim()
    assert hi - lo >= 2.5  # one bar, not a wall across the chart
    bottom, top = ax.get_ylim()
    assert bottom == 0 and top >= max(1.0, area)  # no negative areas around an unchanged visit
    afd_bottom, afd_top = ax_afd.get_ylim()
    assert afd_bottom == 0 and afd_top >= 3.0  # the success limit is on the chart, not a zoom on 0.40-0.44 px


def test_areas_are_printed_to_the_precision_of_the_pixels():
    assert area_mm2_text(975.97, 195) == "976 mm²"  # 5 mm² per pixel
    assert area_mm2_text(3.4821, 87) == "3.48 mm²"  # 0.04 mm² per pixel
    assert area_mm2_text(12.345, 40, unit=False) == "12.3"  # 0.31 mm² per pixel
    assert area_mm2_text(0.0, 0) == "0 mm²"
    assert area_mm2_text(None, 10) == "–"
    assert round_area_mm2(975.97, 195) == 976


def _coarse_pixel_result():
    """A comparison whose pixels cover 5 mm² each, with one region."""
    ref = textured_scene(192)
    changed = ref.copy()
    cv2.circle(changed, (60, 130), 8, 0.95, -1)
    rgb = lambda g: np.repeat(g[:, :, None], 3, axis=2)  # noqa: E731
    cur = translate(changed, 0.6, -0.4)
    result = detect_changes([rgb(ref)], [rgb(cur)], pixel_area_mm2=np.full((192, 192), 5.0 + 1e-3 / 3))
    return rgb(ref), rgb(cur), result


def test_report_areas_have_no_digits_finer_than_a_pixel():
    ref, cur, result = _coarse_pixel_result()
    assert result.regions
    html = diff_products(ref_images=[ref], cur_images=[cur], result=result)["report.html"].decode()
    region = result.regions[0]
    assert f"{region.area_mm2:.2f}" not in html and f"{region.area_mm2:.1f} mm²" not in html
    assert f"<td>{round(region.area_mm2):.0f}</td>" in html


def test_overlay_png_carries_a_legend_below_the_unchanged_map():
    ref, cur, result = _coarse_pixel_result()
    files = diff_products(ref_images=[ref], cur_images=[cur], result=result)
    overlay = cv2.cvtColor(
        cv2.imdecode(np.frombuffer(files["overlay.png"], np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB
    )
    h, w = ref.shape[:2]
    assert overlay.shape[1] == w and overlay.shape[0] > h + 10
    plain = change_overlay(
        ref,
        result.labels,
        result.regions,
        valid=result.valid,
        set_aside=result.edge_explained,
        candidates=result.candidates,
    )
    np.testing.assert_array_equal(overlay[:h], plain)  # the map itself stays pixel-aligned with the reference
    band = overlay[h:]
    assert (band == 255).all(axis=2).mean() > 0.5  # a white band with dark text
    assert (band.max(axis=2) < 80).any()


def test_legend_names_only_what_is_drawn():
    relief = ChangeRegion(
        id=1,
        area_px=10,
        area_mm2=None,
        bbox_xywh=(0, 0, 3, 3),
        centroid_xy=(1, 1),
        mean_score=5,
        max_score=6,
        cue="relief",
    )
    plain = ChangeRegion(
        id=2, area_px=10, area_mm2=None, bbox_xywh=(0, 0, 3, 3), centroid_xy=(1, 1), mean_score=5, max_score=6
    )
    texts = [e.text for e in overlay_legend_entries([relief, plain], set_aside=True, candidates=True)]
    assert any("relief" in t for t in texts) and any("no cue" in t for t in texts)
    colours = {e.colour for e in overlay_legend_entries([relief], set_aside=True, candidates=True)}
    assert SET_ASIDE_RGB in colours and CANDIDATE_RGB in colours
    texts = [e.text for e in overlay_legend_entries([])]
    assert texts == ["no change reported"]


def test_fdf_arrows_of_a_sub_pixel_field_stay_small():
    width = 1280
    calm = 0.2 * fdf_magnification(0.2, width)
    assert calm <= 0.01 * width  # a 0.2 px field is drawn at most 1 % of the width, not 4 %
    assert fdf_magnification(0.2, width) == fdf_magnification(3.0, width)
    large = 20.0 * fdf_magnification(20.0, width)
    assert abs(large - 0.04 * width) <= 0.01 * width  # a large field still gets readable arrows


def test_report_names_simulator_truth_only_when_the_log_holds_it():
    ref, cur, result = _coarse_pixel_result()
    estimates = relocation_log_rows(_Visit(_logged_rows(with_truth=False)))
    with_truth = relocation_log_rows(_Visit(_logged_rows(with_truth=True)))
    plain = diff_products(
        ref_images=[ref], cur_images=[cur], result=result, context=ReportContext(relocation_log=estimates)
    )["report.html"]
    simulated = diff_products(
        ref_images=[ref], cur_images=[cur], result=result, context=ReportContext(relocation_log=with_truth)
    )["report.html"]
    assert b"the tool&#x27;s own estimates" in plain and b"simulator" not in plain
    assert b"the simulator&#x27;s truth" in simulated


def test_history_dates_visit_names_with_milliseconds():
    from fgcd_cli.report.html_page import _human_date

    assert _human_date("20261125T175551460Z") == "2026-11-25 17:55 UTC"  # the store names visits to the millisecond
    assert _human_date("20250601T000000Z") == "2025-06-01 00:00 UTC"
