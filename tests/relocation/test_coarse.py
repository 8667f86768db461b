"""Active coarse stage (paper 001): camera uncertainty against synthetic ground truth, and the stage's choices.

The scene is a relief: a 1.2 m x 0.9 m panel at 1.5 m with bumps of 3-6 cm
(non-planar, so a depth registration is well posed), sampled densely as the
reference cloud. The observation is the same relief seen from the true camera,
with 1.5 mm of noise per axis and its own sampling (a VSE cloud, not a copy).
"""

from __future__ import annotations

import contextlib
import math
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.relocation.coarse.camera_uncertainty import camera_uncertainty, render_visible_points
from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import exp_se3, invert_pose, pose_distance

CAMERA = PinholeCamera(fx=600.0, fy=600.0, cx=320.0, cy=240.0, width=640, height=480)


def _relief(n: int, rng: np.random.Generator) -> np.ndarray:
    x = rng.uniform(-0.6, 0.6, n)
    y = rng.uniform(-0.45, 0.45, n)
    z = (
        1.5
        + 0.04 * np.sin(x / 0.09) * np.cos(y / 0.07)
        + 0.06 * np.exp(-((x - 0.2) ** 2 + (y + 0.1) ** 2) / 0.02)
        - 0.03 * np.exp(-((x + 0.3) ** 2 + (y - 0.15) ** 2) / 0.01)
    )
    return np.column_stack([x, y, z])


def _observed(T_ref_cam_true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    pts = _relief(60000, rng)
    seen = render_visible_points(pts, T_ref_cam_true, CAMERA, stride_px=2)
    return seen + rng.normal(0.0, 0.0015, seen.shape)


@pytest.fixture(scope="module")
def reference_points() -> np.ndarray:
    return _relief(120000, np.random.default_rng(1))


def test_rendering_keeps_only_the_visible_front_surface():
    rng = np.random.default_rng(0)
    n = 20000  # ~3.7 points per 4-px bin: a hidden point shows only through the ~2.5 % empty bins
    front = np.column_stack([rng.uniform(-0.3, 0.3, n), rng.uniform(-0.2, 0.2, n), np.full(n, 1.0)])
    behind = front.copy()
    behind[:, 2] = 2.0  # hidden behind the front sheet
    outside = np.array([[5.0, 0.0, 1.0], [0.0, 0.0, -1.0]])  # beyond the image, behind the camera
    seen = render_visible_points(np.vstack([front, behind, outside]), np.eye(4), CAMERA, stride_px=4)
    assert np.sum(seen[:, 2] < 1.05) > 0.99 * n
    assert np.sum(seen[:, 2] > 1.05) < 0.05 * n
    assert np.all(seen[:, 2] > 0)


@pytest.mark.parametrize("error", [(0.03, 0.0, 0.0, 0.0, 0.0, 2.0), (-0.015, 0.02, 0.01, 1.5, -1.0, 0.5)])
def test_camera_uncertainty_measures_a_small_pose_error_and_corrects_it(reference_points, error):
    rng = np.random.default_rng(2)
    T_true = exp_se3(np.r_[0.02, -0.03, 0.05, np.radians([2.0, -3.0, 1.0])])
    obs = _observed(T_true, rng)
    dt, rot = np.r_[error[:3]], np.radians(error[3:])
    T_est = T_true @ exp_se3(np.r_[dt, rot])
    unc = camera_uncertainty(obs, reference_points, T_est, CAMERA)
    true_mm, true_deg = pose_distance(T_est, T_true)
    # The residual is the pose error (within a few mm and a few tenths of a degree: noise 1.5 mm, 5k points).
    assert abs(unc.translation_m * 1e3 - true_mm) < 5.0
    assert abs(unc.rotation_deg - true_deg) < 0.5
    # the relief's weakest direction (rotation about the optical axis) is at 0.5 % of the strongest: weak
    # by the default limit, so only the image localizer's estimate verifies here, on the constrained part
    assert unc.verified(CoarseConfig(), geometric_source=False)
    assert unc.constrained_translation_m <= unc.translation_m + 1e-9
    # with a lower limit nothing is weak, and a 3D estimate verifies too
    strict = CoarseConfig(weak_ratio=0.002)
    unc_strict = camera_uncertainty(obs, reference_points, T_est, CAMERA, config=strict)
    assert unc_strict.weak_directions == 0 and unc_strict.verified(strict)
    err_mm, err_deg = pose_distance(T_est @ unc.T_correction, T_true)
    assert err_mm < 4.0 and err_deg < 0.3


def test_a_far_wrong_estimate_is_not_verified(reference_points):
    rng = np.random.default_rng(3)
    T_true = np.eye(4)
    obs = _observed(T_true, rng)
    T_est = exp_se3(np.r_[0.25, 0.0, -0.1, 0.0, np.radians(15.0), 0.0])
    unc = camera_uncertainty(obs, reference_points, T_est, CAMERA)
    assert not unc.verified(CoarseConfig())


def test_too_little_observation_gives_infinite_uncertainty(reference_points):
    unc = camera_uncertainty(np.zeros((20, 3)) + [0, 0, 1.5], reference_points, np.eye(4), CAMERA)
    assert math.isinf(unc.translation_m) and not unc.verified(CoarseConfig())


class _FakeSession:
    """A camera on a perfect platform over the relief; the VSE map is the ``ref`` frame moved by ``T_map_ref``
    and scaled by 1 / ``scale`` (what a monocular session's map is)."""

    def __init__(
        self, T_ref_cam: np.ndarray, X: np.ndarray, cloud_ref: np.ndarray, T_map_ref: np.ndarray, scale: float
    ):
        self.T_ref_cam, self.X, self.T_map_ref, self.scale = T_ref_cam.copy(), X, T_map_ref, scale
        self.cloud_map = (cloud_ref @ T_map_ref[:3, :3].T + T_map_ref[:3, 3]) / scale
        self.timing = SimpleNamespace(wait_s=0.0, total_s=0.0)
        self.settle_frames = 2
        self.motions: list[np.ndarray] = []

    def tracking_state(self):
        T = self.T_map_ref @ self.T_ref_cam
        T[:3, 3] /= self.scale
        return SimpleNamespace(T_map_cam=T, cloud=SimpleNamespace(points=self.cloud_map))

    def settle(self, frames=None):
        return self.tracking_state()

    @contextlib.contextmanager
    def standing_still(self, *, stills=0):
        yield

    def move_by(self, M_flange: np.ndarray) -> float:
        self.motions.append(M_flange.copy())
        self.T_ref_cam = self.T_ref_cam @ invert_pose(self.X) @ M_flange @ self.X
        return 0.0


def _stage(session, reference_points, init, evaluate=None, **config):
    from fgcd_cli.alignment.reference import ReferenceIndex
    from fgcd_cli.relocation.coarse.stage import run_coarse
    from fgcd_cli.relocation.coarse.stage_inputs import CoarseInputs

    ref = SimpleNamespace(points=reference_points, T_ref_camref=np.eye(4))
    return run_coarse(
        CoarseInputs(
            session=session,
            reference=ref,
            ref_index=ReferenceIndex(reference_points),
            camera=CAMERA,
            scale=session.scale,
            T_flange_cam=session.X,
            init=init,
            reference_images=None,
            grab_current=None,
            config=CoarseConfig(**config),
            evaluate=evaluate,
        )
    )


X_HANDEYE = exp_se3(np.r_[0.03, -0.05, 0.12, np.radians([1.0, 2.0, 90.0])])


def test_a_far_verified_start_is_walked_to_the_reference_in_bounded_steps(reference_points):
    from fgcd_core.sim3 import Sim3

    T_start = exp_se3(np.r_[0.16, -0.08, 0.05, np.radians([3.0, 9.0, -2.0])])  # 185 mm / ~10 deg away
    T_map_ref = exp_se3(np.r_[0.4, 0.1, -0.2, 0.3, -0.2, 0.1])
    cloud = _relief(30000, np.random.default_rng(5))
    session = _FakeSession(T_start, X_HANDEYE, cloud, T_map_ref, scale=1.7)
    # the first estimate is the truth off by 15 mm / 1 deg (what the passive localizer might give)
    T_ref_map = invert_pose(T_map_ref) @ exp_se3(np.r_[0.01, 0.01, -0.005, 0.0, np.radians(1.0), 0.0])
    init = Sim3(T_ref_map[:3, :3], T_ref_map[:3, 3], 1.0)
    # (no images here, so only the 3D localizer runs: a limit at which the relief has no weak direction)
    result = _stage(session, reference_points, init, weak_ratio=0.002)
    assert result.handed_over, result.reason
    cfg = CoarseConfig()
    # every commanded motion respects the step limits; several were needed
    assert len(session.motions) >= 2
    for M in session.motions:
        mm, deg = pose_distance(np.eye(4), M)
        assert mm <= cfg.step_m * 1e3 + 1e-6 and deg <= cfg.step_deg + 1e-6
    # the camera truly ends within the paper's 5 cm / 5 deg, and the hand-over alignment agrees with the truth
    mm, deg = pose_distance(session.T_ref_cam, np.eye(4))
    assert mm < 50.0 and deg < 5.0
    T_est = result.init.transform_pose(_metric(session.tracking_state().T_map_cam, session.scale))
    err_mm, err_deg = pose_distance(T_est, session.T_ref_cam)
    assert err_mm < 10.0 and err_deg < 0.5


def _metric(T_map_cam: np.ndarray, scale: float) -> np.ndarray:
    T = np.array(T_map_cam, dtype=float)
    T[:3, 3] *= scale
    return T


def test_an_unverifiable_observation_only_looks_around_then_pauses():
    from fgcd_core.sim3 import Sim3

    # the camera sees a flat wall 0.6 m nearer than the relief: nothing the reference can explain
    rng = np.random.default_rng(6)
    wall = np.column_stack([rng.uniform(-0.5, 0.5, 1500), rng.uniform(-0.4, 0.4, 1500), np.full(1500, 0.9)])
    T_start = exp_se3(np.r_[0.15, 0.0, 0.0, 0.0, np.radians(10.0), 0.0])
    session = _FakeSession(T_start, X_HANDEYE, wall, np.eye(4), scale=1.0)
    # (a small reference keeps the 3D localizer's multi-start search, which runs at every view, cheap)
    result = _stage(session, _relief(8000, rng), Sim3(np.eye(3), np.zeros(3), 1.0), max_looks=1)
    assert not result.handed_over and "no estimate verified" in result.reason
    assert [s.action for s in result.steps] == ["look", "pause"]
    # looks are small pure rotations of the camera: it never translated towards an unverified estimate
    for M in session.motions:
        M_cam = invert_pose(X_HANDEYE) @ M @ X_HANDEYE
        assert np.linalg.norm(M_cam[:3, 3]) < 1e-9
        assert pose_distance(np.eye(4), M_cam)[1] <= 2 * CoarseConfig().look_deg + 1e-6
    # giving up, it turned back: the loop starts from where the stage did
    mm, deg = pose_distance(session.T_ref_cam, T_start)
    assert mm < 1e-6 and deg < 1e-6


def test_a_pause_undoes_a_descent_on_an_unverified_estimate(monkeypatch):
    """Paper 001's descent follows an estimate nothing verified; when no view verifies anything after it, the
    stage pauses with the camera back where it started, not where the unverified estimate led it."""
    from fgcd_cli.relocation.coarse import stage
    from fgcd_cli.relocation.coarse.camera_uncertainty import CameraUncertainty  # noqa: F401
    from fgcd_cli.relocation.coarse.passive import View
    from fgcd_core.sim3 import Sim3

    T_start = exp_se3(np.r_[0.04, 0.0, 0.0, 0.0, np.radians(3.0), 0.0])
    session = _FakeSession(T_start, X_HANDEYE, _relief(2000, np.random.default_rng(2)), np.eye(4), scale=1.0)
    wrong = exp_se3(np.r_[-0.08, 0.03, 0.0, 0.0, 0.0, 0.0])  # an unverified estimate that is simply wrong
    unc = SimpleNamespace(translation_m=0.05, constrained_translation_m=0.05)
    views = iter(
        [View(T_cur_cam=np.eye(4), notes={}, best=None, unverified=("3d", wrong, unc))]
        + [View(T_cur_cam=np.eye(4), notes={}, best=None)] * 10
    )
    monkeypatch.setattr(stage, "localize", lambda inp, step, last_3d: next(views))
    monkeypatch.setattr(stage, "_why_not_verified", lambda notes, config: "nothing")
    # the evaluator's truth: where the camera is when asked (evaluation only)
    where = lambda: {"T_ref_cam": session.T_ref_cam.copy()}  # noqa: E731
    result = _stage(
        session, _relief(2000, np.random.default_rng(3)), Sim3(np.eye(3), np.zeros(3), 1.0), where, max_looks=1
    )
    assert [s.action for s in result.steps] == ["descend", "look", "pause"]
    assert "undone" in result.reason
    mm, deg = pose_distance(session.T_ref_cam, T_start)
    assert mm < 1e-6 and deg < 1e-6
    # the truth reported at the end is where the camera was left, not the last view localized before the undo
    assert pose_distance(result.end_truth["T_ref_cam"], T_start)[0] < 1e-6
    assert pose_distance(result.steps[-1].truth["T_ref_cam"], T_start)[1] > 1.0  # (that view was turned away)


def test_bench_coarse_is_registered_with_quick_and_json():
    from typer.testing import CliRunner

    from fgcd_cli.cli.app import app

    result = CliRunner().invoke(app, ["bench", "coarse", "--help"])
    assert result.exit_code == 0
    assert "--quick" in result.output and "--json" in result.output
    from fgcd_cli.bench import coarse

    assert {c.name for c in coarse.CASES} >= set(coarse.QUICK)


def test_a_body_of_revolution_leaves_its_slide_out_of_the_verification():
    """A column (cylinder, axis vertical, radius 0.4 m, 1.5 m from the camera): an orbit about its axis
    and a shift along it change nothing the geometry sees. An estimate off by such a slide plus 20 mm
    towards the column: the constrained residual is the 20 mm, and the slide is named as weak."""
    rng = np.random.default_rng(7)

    def column(n):
        a = rng.uniform(-np.pi / 2, np.pi / 2, n)  # the half facing the camera
        y = rng.uniform(-1.0, 1.0, n)
        return np.column_stack([0.4 * np.sin(a), y, 1.5 - 0.4 * np.cos(a)])

    reference = column(150000)
    T_true = np.eye(4)
    obs = render_visible_points(column(80000), T_true, CAMERA, stride_px=2)
    obs = obs + rng.normal(0.0, 0.0015, obs.shape)
    c = np.array([0.0, 0.0, 1.5])
    orbit = exp_se3(np.r_[0.0, 0.0, 0.0, 0.0, np.radians(3.0), 0.0])
    T_orbit = np.eye(4)
    T_orbit[:3, :3], T_orbit[:3, 3] = orbit[:3, :3], c - orbit[:3, :3] @ c
    T_est = T_orbit @ T_true @ exp_se3(np.r_[0.0, 0.03, 0.02, 0.0, 0.0, 0.0])  # + 30 mm along the axis
    unc = camera_uncertainty(obs, reference, T_est, CAMERA)
    assert unc.weak_directions >= 1
    # what geometry can check is the 20 mm towards the column (within the noise and the projection's mixing)
    assert abs(unc.constrained_translation_m * 1e3 - 20.0) < 6.0
    assert unc.verified(CoarseConfig(), geometric_source=False)


def _scale_error_run(reference_points, monkeypatch, *, scale_error: float, scale_rel_std: float):
    """The coarse stage from 41 mm / 1.6 deg with the session's scale ``1 + scale_error`` too large and an
    exact image localizer (a textured object near the reference): ``(result, session)``."""
    from fgcd_cli.alignment.reference import ReferenceIndex
    from fgcd_cli.relocation.coarse import passive
    from fgcd_cli.relocation.coarse.stage import run_coarse
    from fgcd_cli.relocation.coarse.stage_inputs import CoarseInputs
    from fgcd_core.sim3 import Sim3

    T_start = exp_se3(np.r_[0.03, -0.02, 0.02, np.radians([0.5, 1.5, 0.0])])  # 41 mm / 1.6 deg away
    cloud = _relief(30000, np.random.default_rng(8))
    session = _FakeSession(T_start, X_HANDEYE, cloud, np.eye(4), scale=1.0)
    # the image localizer measures the camera exactly (a textured object near the reference)
    monkeypatch.setattr(
        passive, "image_estimate", lambda **_kw: (session.T_ref_cam.copy(), {"pnp": "ok", "inliers": 500})
    )
    ref = SimpleNamespace(points=reference_points, T_ref_camref=np.eye(4))
    result = run_coarse(
        CoarseInputs(
            session=session,
            reference=ref,
            ref_index=ReferenceIndex(reference_points),
            camera=CAMERA,
            scale=1.0 + scale_error,
            scale_rel_std=scale_rel_std,
            T_flange_cam=X_HANDEYE,
            init=Sim3(np.eye(3), np.zeros(3), 1.0 / (1.0 + scale_error)),
            reference_images={"front": np.zeros((480, 640), np.float32)},
            grab_current=lambda: None,
        )
    )
    return result, session


def test_a_verified_image_estimate_is_not_moved_by_the_session_scale_error(reference_points, monkeypatch):
    """The session's scale 2 % too large (what a short exploration gives). The alignment measures the
    ratio (its Sim3 scale), the check registers at it, and the stage walks to the estimate as PnP gave it:
    a correction by a check at the session's scale would leave the camera 2 % of 1.5 m = 30 mm off."""
    result, session = _scale_error_run(reference_points, monkeypatch, scale_error=0.02, scale_rel_std=0.02)
    assert result.handed_over, result.reason
    assert any(s.source == "image" and s.action in ("move", "handover") for s in result.steps)
    # the check's scale is the alignment's, about 1/1.02 (the fit's own error is a fraction of a %)
    scales = [s.estimates[k]["check_scale"] for s in result.steps for k in ("3d", "image")]
    assert all(abs(c * 1.02 - 1.0) < 0.005 for c in scales), scales
    # the camera truly ends at the reference (an exact estimate, an exact platform)
    mm, deg = pose_distance(session.T_ref_cam, np.eye(4))
    assert mm < 3.0 and deg < 0.2


def test_an_exact_image_estimate_verifies_through_a_large_session_scale_error(reference_points, monkeypatch):
    """A 5 % scale error (the statue's revisit, docs/lab/2026-11-27-coarse-far-starts.md) shifts a check at the
    session's scale by 5 % of 1.5 m = 75 mm, beyond the 50 mm limit, at the true pose: nothing could verify.
    The image estimate is checked at the scale the alignment measured, whatever sigma the session claims (1 %
    here: the fit does not count the map's drift), and verifies; the 3D estimate, checked at its own scale only
    within the session's 3 sigma, keeps the session's. A metric session (sigma 0) keeps its own scale for both,
    and the same exact estimate is refused, not moved."""
    for claimed in (0.04, 0.01):
        result, session = _scale_error_run(reference_points, monkeypatch, scale_error=0.05, scale_rel_std=claimed)
        assert result.handed_over, (claimed, result.reason)
        mm, _deg = pose_distance(session.T_ref_cam, np.eye(4))
        assert mm < 3.0
        first = result.steps[0].estimates
        assert abs(first["image"]["check_scale"] * 1.05 - 1.0) < 0.005
        assert first["3d"]["check_scale"] == (first["image"]["check_scale"] if claimed == 0.04 else 1.0)
    refused, session = _scale_error_run(reference_points, monkeypatch, scale_error=0.05, scale_rel_std=0.0)
    assert not refused.handed_over
    assert all(s.estimates[k]["check_scale"] == 1.0 for s in refused.steps for k in ("3d", "image"))
    image_notes = [s.estimates["image"]["uncertainty"] for s in refused.steps if "image" in s.estimates]
    assert min(n["constrained_translation_mm"] for n in image_notes) > 50.0


def test_the_check_takes_the_alignment_scale_within_the_session_s_error_or_when_measured():
    from fgcd_cli.relocation.coarse.passive import check_scale

    assert check_scale(0.95, scale_rel_std=0.04) == 0.95  # 5 % against 3 x 4 %
    assert check_scale(0.95, scale_rel_std=0.01) == 1.0  # 5 % against 3 x 1 %: the alignment is suspect
    assert check_scale(1.0 / 0.93, scale_rel_std=0.02) == 1.0  # 7.3 % against 6 %
    assert check_scale(float("nan"), scale_rel_std=0.1) == 1.0
    assert check_scale(0.99, scale_rel_std=0.0) == 1.0  # a metric session trusts its depth
    # an alignment that measured its scale gives the ratio for an estimate independent of it (monocular session)
    assert check_scale(0.93, scale_rel_std=0.01, scale_measured=True) == 0.93
    assert check_scale(0.93, scale_rel_std=0.0, scale_measured=True) == 1.0
    assert check_scale(float("nan"), scale_rel_std=0.01, scale_measured=True) == 1.0
