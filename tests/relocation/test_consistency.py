"""Every 3D estimate of a run is of one map-to-reference transform: estimates that follow the camera are caught.

The failure this guards against (Fig. 7's statue under a low side light, docs/relocation.md "Estimates that
follow the camera"): each alignment places the camera at the same offset from the reference whatever the
camera did, so the loop keeps commanding the same motion and walks the camera away from the object's
reference pose. Stand-ins: an exact VSE over an exact platform, an aligner whose estimate follows the camera.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.config import ReferenceData, RelocationConfig
from fgcd_cli.relocation.image.refine import ImageRefinement
from fgcd_cli.relocation.loop.context import LoopContext
from fgcd_cli.relocation.loop.parallel import relocate
from fgcd_cli.relocation.racr.aligner import AlignmentEstimate
from fgcd_cli.relocation.racr.consistency import estimate_spread
from fgcd_cli.relocation.session import VseSession
from fgcd_core.camera import PinholeCamera
from fgcd_core.platform import GuardLimits, MotionGuard
from fgcd_core.se3 import exp_se3, invert_pose, pose_distance
from fgcd_core.sim3 import Sim3
from tests.relocation.test_loop import ExactVse, make_case

CAMERA = PinholeCamera(fx=600, fy=600, cx=319.5, cy=239.5, width=640, height=480)
DEPTH_M = 1.5
SIGMA_MM = 1000 * RelocationConfig().vse_sigma_rel * DEPTH_M  # one estimate's 1-sigma at this depth (15 mm)
BOUND_MM = RelocationConfig().agreement_k * math.sqrt(2) * SIGMA_MM  # two estimates' agreement bound (42.4 mm)


# ----------------------------------------------------------------------------- the test itself
def test_estimates_of_one_transform_agree_within_both_uncertainties():
    T = Sim3.from_pose(exp_se3([0.1, -0.2, 0.3, 0.05, 0.02, -0.1]))
    cam = exp_se3([0.02, 0.01, -0.03, 0.0, 0.1, 0.0])
    within = Sim3.from_pose(exp_se3([0.9 * BOUND_MM / 1000, 0, 0, 0, 0, 0])) @ T
    beyond = Sim3.from_pose(exp_se3([0, 1.1 * BOUND_MM / 1000, 0, 0, 0, 0])) @ T
    assert estimate_spread(T, [], cam, sigma_mm=SIGMA_MM, k=2.0).agree  # nothing to compare
    same = estimate_spread(T, [T], cam, sigma_mm=SIGMA_MM, k=2.0)
    assert same.agree and same.distance_mm == pytest.approx(0.0, abs=1e-9)
    ok = estimate_spread(within, [T], cam, sigma_mm=SIGMA_MM, k=2.0)
    assert ok.agree and ok.distance_mm == pytest.approx(0.9 * BOUND_MM, rel=1e-6)
    assert ok.bound_mm == pytest.approx(BOUND_MM, rel=1e-9)
    # the farthest earlier estimate decides, wherever it is in the list
    bad = estimate_spread(beyond, [T, within, beyond], cam, sigma_mm=SIGMA_MM, k=2.0)
    assert not bad.agree and bad.against in (0, 1)
    assert bad.distance_mm > BOUND_MM
    assert estimate_spread(beyond, [T], cam, sigma_mm=math.inf, k=2.0).agree  # no model: nothing tested


def test_a_rotation_of_the_transform_is_measured_at_the_camera():
    """Two estimates that differ by a turn about the map origin disagree by the arc the camera travels."""
    T = Sim3()
    turned = Sim3.from_pose(exp_se3([0, 0, 0, 0, 0, 0.05]))  # 0.05 rad about z
    cam = exp_se3([1.0, 0, 0, 0, 0, 0])  # 1 m from the axis
    spread = estimate_spread(turned, [T], cam, sigma_mm=SIGMA_MM, k=2.0)
    assert spread.distance_mm == pytest.approx(2000 * math.sin(0.025), rel=1e-6)  # chord of 0.05 rad at 1 m
    assert not spread.agree


# ----------------------------------------------------------------------------- the loop
def _case(*, follow: bool, image: bool, mode: str = "serial"):
    """A reference at 1.5 m; the aligner either follows the camera (every estimate puts it 20 mm to the side of
    the reference, whatever it did) or is consistently 8 mm off (a biased but fixed estimate). ``image``: an
    exact image stage. Returns (result or AlgorithmError, true final offset mm, true offset at the start mm)."""
    X, platform, T_map_base, s, T_ref_camref, T_ref_cur, T_ref_base = make_case()
    u, v = np.meshgrid(np.linspace(-0.4, 0.4, 9), np.linspace(-0.3, 0.3, 7))
    pts = (
        np.column_stack([u.ravel(), v.ravel(), np.full(u.size, DEPTH_M)]) @ T_ref_camref[:3, :3].T + T_ref_camref[:3, 3]
    )
    true_cam = lambda: T_ref_base @ platform.true @ X  # noqa: E731
    aside = T_ref_camref @ exp_se3([0.02, 0.0, 0.0, 0.0, 0.0, 0.0])
    biased = Sim3.from_pose(exp_se3([0.008, 0.0, 0.0, 0.0, 0.005, 0.0])) @ T_ref_cur

    def aligner(*, serial=0, state=None, **_kw):
        T_cur_cam = np.array(state.T_map_cam, dtype=float)
        T_cur_cam[:3, 3] *= s
        T = Sim3.from_pose(aside @ invert_pose(T_cur_cam)) if follow else biased
        return [
            AlignmentEstimate(
                T_ref_cur=T,
                stage="fast",
                ok=True,
                reason="ok",
                vse_frame=state.frames_processed,
                seconds=0.0,
                serial=serial,
            )
        ]

    def refine(**_kw):
        T = true_cam()
        return ImageRefinement(
            ok=True,
            reason="ok",
            M_cam=invert_pose(T) @ T_ref_camref,
            measured_afd_px=0.1 + 600.0 * pose_distance(T, T_ref_camref)[0] / 1000 / DEPTH_M,
            matches=400,
            inliers=350,
            rms_px=0.3,
            matcher="sift",
            offset_sigma_mm=0.3,
        )

    start_mm = pose_distance(true_cam(), T_ref_camref)[0]
    vse = ExactVse(platform, X, T_map_base, s)
    session = VseSession(
        guard=MotionGuard(platform, GuardLimits(max_step_m=0.1, max_step_rad=0.5)),
        vse=vse,
        substep_m=1.0,
        substep_rad=1.0,
    )
    ref = ReferenceData(points=pts, intensities=np.zeros(len(pts)), T_ref_camref=T_ref_camref)
    extra = (
        dict(
            reference_images={"front": np.zeros((480, 640), np.float32)},
            grab_current=lambda: np.zeros((480, 640), np.float32),
            image_refiner=refine,
        )
        if image
        else {}
    )
    try:
        out = relocate(
            LoopContext(
                session=session,
                reference=ref,
                ref_index=None,
                camera=CAMERA,
                scale=s,
                T_flange_cam=X,
                init=Sim3(),
                aligner=aligner,
                **extra,
                config=RelocationConfig(mode=mode, eta=1e-6, agreement_wait_s=2.0),
            )
        )
    except AlgorithmError as exc:
        out = exc
    finally:
        vse.stop()
    return out, pose_distance(true_cam(), T_ref_camref)[0], start_mm


def test_estimates_that_follow_the_camera_pause_the_loop_before_it_walks_away():
    out, end_mm, start_mm = _case(follow=True, image=False)
    assert isinstance(out, AlgorithmError)
    assert "follow the camera" in str(out)
    # each estimate commands the same 20 mm: the pause comes once two estimates are more than the agreement
    # bound apart, i.e. after ceil(42.4 / 20) = 3 motions, not after the 12 adjustments allowed (~240 mm)
    assert end_mm < start_mm + 3 * 20.0 + 1.0


@pytest.mark.parametrize("mode", ["serial", "parallel"])
def test_estimates_that_follow_the_camera_hand_over_to_the_image_stage(mode):
    out, end_mm, _ = _case(follow=True, image=True, mode=mode)
    assert not isinstance(out, AlgorithmError), out
    assert out.converged
    assert "3D alignment inconsistent" in out.reason
    assert out.residual is not None and out.residual.source == "image"
    assert "image stage (3D inconsistent)" in out.reason
    assert str(out.residual.agreement).startswith("not checked")  # stopped without the alignment's vote
    assert end_mm < 1e-3


def test_a_fixed_bias_is_not_taken_for_estimates_that_follow_the_camera():
    """Negative control: an 8 mm bias, the same in every estimate, is one transform (estimated wrong); the image
    stage removes it with the alignment's usual vote."""
    out, end_mm, _ = _case(follow=False, image=True)
    assert not isinstance(out, AlgorithmError), out
    assert out.converged
    assert "inconsistent" not in out.reason and "follow the camera" not in out.reason
    assert end_mm < 1e-3
