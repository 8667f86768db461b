"""A correction beyond what ordinary image evidence moves: one ordinary step toward it, corroborated by the next
measurement (relocation/image/probe.py; docs/relocation.md, "A large correction on ordinary evidence").

Stand-ins: the 3D alignment never trusts itself (the image fallback runs, nothing else can vouch for an image
estimate); the image refiner refuses corrections beyond 20 mm / 1.5 deg as "unverified" (ordinary evidence),
keeping the estimate and its ordinary step, as ``image_refine`` does.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.adjustment import clamp_motion
from fgcd_cli.relocation.image.probe import corroborates, predict_after_step
from fgcd_cli.relocation.image.refine import ImageRefinement
from fgcd_core.se3 import exp_se3, invert_pose, pose_distance
from tests.relocation.test_loop import _degenerate_case_with_image_fallback, frames_afd_px

LIMIT_M, LIMIT_DEG = 0.02, 1.5  # ImageRefineConfig's ordinary limit
SIGMA_MM = 0.5  # the stand-in's PnP uncertainty


def _refinement(M, T_true, T_ref_camref):
    mm, deg = pose_distance(np.eye(4), M)
    common = dict(
        M_cam=M,
        measured_afd_px=frames_afd_px(T_true, T_ref_camref),
        matches=60,
        inliers=45,
        rms_px=0.4,
        matcher="sift",
        offset_sigma_mm=SIGMA_MM,
    )
    if mm <= 1000 * LIMIT_M and deg <= LIMIT_DEG:
        return ImageRefinement(ok=True, reason="ok", **common)
    step, _ = clamp_motion(M, max_step_m=LIMIT_M, max_step_rad=math.radians(LIMIT_DEG))
    return ImageRefinement(
        ok=False,
        reason=f"correction of {mm:.1f} mm is too large to trust on 45 inliers",
        unverified=True,
        step_M_cam=step,
        **common,
    )


def test_a_true_estimate_predicts_the_next_measurement_and_a_stuck_one_does_not():
    T_ref_camref = exp_se3([0.1, 0.2, -0.3, 0.1, -0.2, 0.05])
    T_true = T_ref_camref @ exp_se3([0.04, -0.02, 0.01, 0.0, 0.02, 0.0])  # 46 mm off
    M = invert_pose(T_true) @ T_ref_camref
    step, _ = clamp_motion(M, max_step_m=LIMIT_M, max_step_rad=math.radians(LIMIT_DEG))
    prediction = predict_after_step(T_ref_camref, M, step, sigma_mm=SIGMA_MM)
    T_after = T_true @ step
    ok, dist, bound = corroborates(
        prediction, T_ref_camref, invert_pose(T_after) @ T_ref_camref, sigma_mm=SIGMA_MM, k=2.0
    )
    assert ok and dist == pytest.approx(0.0, abs=1e-6)
    assert bound == pytest.approx(2 * math.sqrt(2) * SIGMA_MM)
    # a fit that does not follow the motion (the same correction again) is one step from the prediction
    ok, dist, _ = corroborates(prediction, T_ref_camref, M, sigma_mm=SIGMA_MM, k=2.0)
    assert not ok and dist == pytest.approx(1000 * np.linalg.norm(step[:3, 3]), rel=1e-9)
    assert 0.9 * 1000 * LIMIT_M <= dist <= 1000 * LIMIT_M


@pytest.mark.parametrize("mode", ["serial", "parallel"])
def test_the_fallback_approaches_a_large_correction_on_ordinary_evidence_and_arrives(monkeypatch, mode):
    seen: list = []

    def honest(T_true, T_ref_camref):
        seen.append(T_true)
        return _refinement(invert_pose(T_true) @ T_ref_camref, T_true, T_ref_camref)

    res, platform, (mm, deg) = _degenerate_case_with_image_fallback(monkeypatch, honest, mode)
    assert res.converged, res.reason
    assert mm < 1e-3 and deg < 1e-3
    first = res.records[0]
    assert first.stage == "image" and not first.alignment_ok and "too large to trust" in first.alignment_reason
    assert first.offset_mm > 1000 * LIMIT_M or first.offset_deg > LIMIT_DEG
    # the first motion was one ordinary step toward it, not the whole correction
    step_mm, step_deg = pose_distance(seen[0], seen[1])
    assert step_mm <= 1000 * LIMIT_M + 1e-6 and step_deg <= LIMIT_DEG + 1e-6


def test_an_estimate_that_does_not_follow_the_motion_ends_the_fallback_after_one_ordinary_step(monkeypatch):
    """Negative control: a fit that gives the same large correction wherever the camera is (a chance fit would
    not predict the next one either). One ordinary step, then the pause; without the corroboration the stage would
    walk 20 mm per step for its 6 steps."""
    seen: list = []

    def same_every_time(T_true, T_ref_camref):
        seen.append(T_true)
        return _refinement(invert_pose(seen[0]) @ T_ref_camref, T_true, T_ref_camref)

    with pytest.raises(AlgorithmError, match="does not follow the motion"):
        _degenerate_case_with_image_fallback(monkeypatch, same_every_time)
    assert len(seen) == 2  # measured, stepped, measured: refused
    step_mm, step_deg = pose_distance(seen[0], seen[1])
    assert 0 < step_mm <= 1000 * LIMIT_M + 1e-6 and step_deg <= LIMIT_DEG + 1e-6
