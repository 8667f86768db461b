"""The campaign diff's statement of the pose it measured, and its check of the relocation's own residual."""

from fgcd_cli.report.pose_check import MEASURED_POSE_ERROR_MM, geometry_text, relocation_check_text

MEASURED = {
    "geometry": {
        "warp": "reference depth and residual pose",
        "residual_pose_mm": 1.10,
        "residual_pose_deg": 0.02,
        "pnp_inliers": 900,
        "pnp_matches": 910,
        "pnp_rms_px": 0.2,
        "depth_fraction": 0.9,
        "depth_edge_fraction": 0.01,
    }
}


def test_a_stated_residual_that_covers_the_measurement_is_confirmed():
    stated = {"offset_mm": 0.74, "sigma_mm": 0.45, "tolerance_mm": 1.0, "source": "image"}
    assert relocation_check_text(stated, MEASURED) == "measured 1.10 mm: within the relocation's stated 0.74 ± 0.45 mm"


def test_an_optimistic_stated_residual_is_contradicted():
    # 0.33 ± 0.17 mm: 2 sigma + the measurement's own error reach 0.33 + 0.34 + 0.7 = 1.37 mm
    assert "within" in relocation_check_text({"offset_mm": 0.33, "sigma_mm": 0.17}, MEASURED)
    far = {"geometry": dict(MEASURED["geometry"], residual_pose_mm=2.0)}
    text = relocation_check_text({"offset_mm": 0.33, "sigma_mm": 0.17}, far)
    assert text.startswith("measured 2.00 mm: beyond") and f"{MEASURED_POSE_ERROR_MM} mm" in text


def test_no_check_without_both_estimates():
    assert relocation_check_text(None, MEASURED) == ""
    assert relocation_check_text({"offset_mm": 0.3, "sigma_mm": 0.1}, {}) == ""
    assert relocation_check_text({"offset_mm": "?"}, MEASURED) == ""


def test_the_warp_line_says_what_was_used():
    assert geometry_text({}) == "homography and flow (no reference depth used)"
    assert geometry_text({"geometry": {"warp": "homography", "reason": "19 matches on the reference depth"}}).endswith(
        "19 matches on the reference depth"
    )
    assert "visit measured 1.10 mm" in geometry_text(MEASURED)
