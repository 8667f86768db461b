"""The ACR baseline: its 5-point (and homography) step points the right way, its bisection converges.

The two-view tests project a synthetic scene into two cameras with a known
relative motion; the loop test runs ACR on a perfect simulated rig (a kinematic
chain with a hidden hand-eye and an exact two-view measurement), so only the
bisection and the identity hand-eye are under test.
"""

import math

import numpy as np
import pytest

from fgcd_cli.errors import AlgorithmError
from fgcd_cli.relocation.acr.baseline import AcrConfig, AcrRig, Bisection, acr_relocate
from fgcd_cli.relocation.acr.pose import AcrModel, AcrPoseConfig, RelativePose, relative_pose_from_matches
from fgcd_cli.relocation.session import SessionTiming
from fgcd_core.se3 import exp_se3, invert_pose, rotation_angle_rad, transform_points

F_PX, W, H = 600.0, 640, 480
K = np.array([[F_PX, 0, W / 2], [0, F_PX, H / 2], [0, 0, 1.0]])


def scene(rng, *, relief_m: float, n: int = 400) -> np.ndarray:
    """Points of an object 1.3 m in front of the reference camera (camera frame = world), metres."""
    xy = rng.uniform(-0.45, 0.45, size=(n, 2)) * [1.0, 0.75]
    z = 1.3 + relief_m * np.sin(7 * xy[:, 0]) * np.cos(5 * xy[:, 1])
    return np.c_[xy, z]


def project(T_world_cam: np.ndarray, points: np.ndarray) -> np.ndarray:
    pc = transform_points(invert_pose(T_world_cam), points)
    return (pc[:, :2] / pc[:, 2:3]) * F_PX + [W / 2, H / 2]


def true_relative(T_world_cam: np.ndarray, T_world_camref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reference camera in the current camera frame: rotation and unit direction."""
    M = invert_pose(T_world_cam) @ T_world_camref
    return M[:3, :3], M[:3, 3] / np.linalg.norm(M[:3, 3])


@pytest.mark.parametrize("model,relief_m", [(AcrModel.ESSENTIAL, 0.08), (AcrModel.HOMOGRAPHY, 0.0)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_two_view_step_points_to_the_reference(model, relief_m, seed):
    rng = np.random.default_rng(seed)
    points = scene(rng, relief_m=relief_m)
    T_world_camref = np.eye(4)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    # a revisit start: 30 mm / 3 deg from the reference
    T_world_cam = exp_se3(np.r_[0.03 * direction, math.radians(3.0) * axis])
    # 0.1 px: SIFT's sub-pixel localisation on sharp features
    p_ref = project(T_world_camref, points) + rng.normal(scale=0.1, size=(len(points), 2))
    p_cur = project(T_world_cam, points) + rng.normal(scale=0.1, size=(len(points), 2))
    pose = relative_pose_from_matches(p_cur, p_ref, K, config=AcrPoseConfig(model=model))
    assert pose.ok, pose.reason
    R_true, t_true = true_relative(T_world_cam, T_world_camref)
    # Points the right way: within 30 deg, a step of up to 2 cos(30 deg) = 1.7 times the offset
    # shrinks it (|d - s u|^2 < |d|^2 iff s < 2 |d| cos angle); the rotation within 0.3 deg
    assert float(np.dot(pose.t_dir, t_true)) > math.cos(math.radians(30.0))
    assert math.degrees(rotation_angle_rad(pose.R_cur_ref.T @ R_true)) < 0.3
    # the measured AFD is the mean displacement of the inlier matches (> 0: the views differ)
    true_afd = float(np.linalg.norm(project(T_world_cam, points) - project(T_world_camref, points), axis=1).mean())
    assert pose.measured_afd_px == pytest.approx(true_afd, rel=0.2)


def test_too_few_matches_is_refused():
    rng = np.random.default_rng(3)
    pose = relative_pose_from_matches(rng.uniform(0, 400, (8, 2)), rng.uniform(0, 400, (8, 2)), K)
    assert not pose.ok and "matches" in pose.reason


def test_bisection_halves_on_reversal_only():
    b = Bisection(0.05)
    assert b.length(np.array([1.0, 0, 0])) == 0.05
    b.moved(np.eye(4), np.array([1.0, 0, 0]))
    assert b.length(np.array([0.9, 0.1, 0])) == 0.05  # same way: kept
    b.moved(np.eye(4), np.array([1.0, 0, 0]))
    assert b.length(np.array([-1.0, 0, 0])) == 0.025  # reversed: halved
    assert b.halvings == 1


class PerfectRig:
    """A kinematic rig: ``T_base_cam = T_base_flange @ X`` with a hidden hand-eye ``X``; exact measurements."""

    def __init__(self, X: np.ndarray, start_offset: np.ndarray, points: np.ndarray):
        self.X = X
        self.T_base_camref = np.eye(4)
        self.T_base_flange = exp_se3(start_offset) @ invert_pose(X)  # camera displaced from the reference
        self.points = points
        self.moves = 0

    def camera(self) -> np.ndarray:
        return self.T_base_flange @ self.X

    def afd_px(self) -> float:
        return float(
            np.linalg.norm(
                project(self.camera(), self.points) - project(self.T_base_camref, self.points), axis=1
            ).mean()
        )

    def measure(self, _ref, _cur, _K, *, config) -> RelativePose:
        R, t = true_relative(self.camera(), self.T_base_camref)
        return RelativePose(
            ok=True, reason="ok", R_cur_ref=R, t_dir=t, matches=400, inliers=400, measured_afd_px=self.afd_px()
        )

    def move(self, M_flange: np.ndarray) -> None:
        self.moves += 1
        self.T_base_flange = self.T_base_flange @ M_flange

    def acr_rig(self) -> AcrRig:
        return AcrRig(grab=lambda: np.zeros((H, W)), move=self.move, timing=SessionTiming(), measure=self.measure)


@pytest.mark.parametrize("handeye_deg", [0.0, 10.0, 25.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_bisection_converges_on_a_perfect_rig(handeye_deg, seed):
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    # hidden hand-eye: a rotation error of handeye_deg and the camera 8 cm off the flange
    X = exp_se3(np.r_[0.0, 0.08, 0.05, math.radians(handeye_deg) * axis / np.linalg.norm(axis)])
    d = rng.normal(size=3)
    a = rng.normal(size=3)
    start = np.r_[0.03 * d / np.linalg.norm(d), math.radians(3.0) * a / np.linalg.norm(a)]
    rig = PerfectRig(X, start, scene(rng, relief_m=0.05))
    assert rig.afd_px() > 5.0
    result = acr_relocate(rig.acr_rig(), np.zeros((H, W)), K, config=AcrConfig())
    assert result.converged, result.reason
    # the stop rule is the measured AFD; on a perfect rig the measurement is the truth
    assert rig.afd_px() <= AcrConfig().stop_afd_px
    assert result.adjustments <= AcrConfig().max_adjustments
    # the bisection is what converged it: the step length was halved at least once
    steps = [r.image["step_mm"] for r in result.records if r.image["step_mm"] > 0]
    assert min(steps) < AcrConfig().initial_step_m * 1e3


def test_without_halving_the_loop_does_not_converge(monkeypatch):
    """A bisection that never halves oscillates about the reference: the test above would catch it."""
    monkeypatch.setattr(Bisection, "length", lambda self, t_dir: self.step_m)
    rng = np.random.default_rng(0)
    rig = PerfectRig(np.eye(4), np.r_[0.03, 0.0, 0.0, 0.0, 0.0, 0.0], scene(rng, relief_m=0.05))
    result = acr_relocate(rig.acr_rig(), np.zeros((H, W)), K, config=AcrConfig(max_adjustments=12))
    assert not result.converged


def test_no_trustworthy_pose_pauses():
    rig = PerfectRig(np.eye(4), np.r_[0.03, 0, 0, 0, 0, 0], scene(np.random.default_rng(0), relief_m=0.05))

    def failing(*_args, config):
        return RelativePose(ok=False, reason="only 3 SIFT matches", R_cur_ref=np.eye(3), t_dir=np.zeros(3))

    acr = AcrRig(grab=lambda: np.zeros((H, W)), move=rig.move, measure=failing)
    with pytest.raises(AlgorithmError, match="ACR paused"):
        acr_relocate(acr, np.zeros((H, W)), K)
    assert rig.moves == 0


@pytest.mark.parametrize("seed", [0, 1])
def test_with_the_hand_eye_the_bisection_needs_no_more_steps(seed):
    """ACR_w/X (paper 000 Table 3): the calibrated hand-eye turns each camera step into the right flange step."""

    def run(with_x: bool):
        rng = np.random.default_rng(seed)
        axis = rng.normal(size=3)
        X = exp_se3(np.r_[0.0, 0.08, 0.05, math.radians(25.0) * axis / np.linalg.norm(axis)])
        d, a = rng.normal(size=3), rng.normal(size=3)
        start = np.r_[0.03 * d / np.linalg.norm(d), math.radians(3.0) * a / np.linalg.norm(a)]
        rig = PerfectRig(X, start, scene(rng, relief_m=0.05))
        result = acr_relocate(
            rig.acr_rig(), np.zeros((H, W)), K, config=AcrConfig(), T_flange_cam=X if with_x else None
        )
        return result, rig.afd_px()

    with_x, afd_x = run(True)
    without, _ = run(False)
    assert with_x.converged and afd_x <= AcrConfig().stop_afd_px
    assert with_x.adjustments <= without.adjustments
