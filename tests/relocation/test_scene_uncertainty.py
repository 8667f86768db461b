"""Scene uncertainty (paper 001, Eq. 2): the map's success models and the look it chooses, on synthetic truth.

The scenes are built so that the right answer follows from the geometry alone: a textured
strip in a recess that a textureless pier hides from the right, a flat wall that no
point-to-plane registration can pin, texture that lies only to one side of the view.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.coarse.scene_uncertainty import (
    SceneModel,
    SceneUncertaintyConfig,
    SceneUncertaintyMap,
    build_scene_model,
    camera_turn,
    predict_view,
    scene_uncertainty_map,
    view_uncertainty,
)
from fgcd_core.camera import PinholeCamera
from fgcd_core.se3 import invert_pose, pose_distance

CAMERA = PinholeCamera(fx=600.0, fy=600.0, cx=320.0, cy=240.0, width=640, height=480)


def _sheet(x0: float, x1: float, y0: float, y1: float, z: float, step: float) -> np.ndarray:
    """A regular grid of points on the plane ``z`` (metres, reference camera frame = ``ref``)."""
    X, Y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)])


@pytest.fixture(scope="module")
def recess():
    """A wall at 1.5 m with a textureless pier at 1.0 m in front of its right half; the only texture
    is a strip of the wall just left of the pier's edge, which the pier hides from cameras on the
    right (a ray from x = +0.25 m to the strip crosses z = 1.0 m right of x = 0) and not from the left."""
    points = np.vstack([_sheet(-0.6, 0.6, -0.4, 0.4, 1.5, 0.006), _sheet(0.0, 0.5, -0.4, 0.4, 1.0, 0.004)])
    rng = np.random.default_rng(0)
    strip = np.column_stack([rng.uniform(-0.12, -0.01, 1000), rng.uniform(-0.4, 0.4, 1000), np.full(1000, 1.5)])
    config = SceneUncertaintyConfig(cells=5, max_points=len(points))  # every point: no z-buffer holes
    model = build_scene_model(
        reference_points=points, T_ref_camref=np.eye(4), camera=CAMERA, keypoints_per_image=[strip], config=config
    )
    return model, config


def test_candidates_that_see_the_texture_are_less_uncertain_than_those_the_pier_blinds(recess):
    model, config = recess
    smap = scene_uncertainty_map(model, CAMERA, config=config)
    assert smap.uncertainty.shape == (1, 5, 5) and smap.n_directions == 5
    assert np.all((smap.uncertainty >= 0) & (smap.uncertainty <= 1))
    left, right = smap.uncertainty[0][:, smap.x_m < 0], smap.uncertainty[0][:, smap.x_m > 0.2]
    # from the left every direction sees the strip: the image localizer succeeds everywhere
    assert np.all(left == 0.0)
    # from the far right the pier hides it in every direction: nothing localizes
    assert np.all(right == 1.0)
    # Eq. 2: U is one minus the fraction of directions where either localizer succeeds
    np.testing.assert_allclose(smap.uncertainty, 1.0 - smap.successes / smap.n_directions)
    assert np.all(smap.successes >= np.maximum(smap.image_successes, smap.geometry_successes))


def test_flat_geometry_leaves_the_3d_localizer_no_success(recess):
    model, config = recess
    smap = scene_uncertainty_map(model, CAMERA, config=config)
    # two parallel planes: translation along them and the turn about their normal are unconstrained
    assert np.all(smap.geometry_successes == 0)
    assert predict_view(model, np.eye(4), CAMERA, config=config).weak_directions == 3


def test_the_predicted_pnp_error_agrees_with_the_localizers_own_covariance(recess):
    """The map's PnP prediction and :func:`pnp_translation_sigma_m` (the localizer's measured covariance)
    agree when the residuals are the stated pixel noise."""
    import cv2

    from fgcd_cli.relocation.image.pnp_uncertainty import pnp_translation_sigma_m

    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-0.4, 0.4, 400), rng.uniform(-0.3, 0.3, 400), rng.uniform(1.3, 1.7, 400)])
    model = SceneModel(
        points=X,
        normals=np.tile([0.0, 0.0, -1.0], (len(X), 1)),
        keypoints=X,
        keypoint_image=np.zeros(len(X), dtype=int),
        T_ref_camref=np.eye(4),
        centroid=X.mean(axis=0),
    )
    config = SceneUncertaintyConfig(min_points=10**9)  # the image localizer only
    pred = predict_view(model, np.eye(4), CAMERA, config=config)
    K = np.array([[CAMERA.fx, 0, CAMERA.cx], [0, CAMERA.fy, CAMERA.cy], [0, 0, 1.0]])
    pixels, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, None)
    noisy = pixels.reshape(-1, 2) + rng.normal(0.0, config.pixel_sigma_px, (len(X), 2))
    measured = pnp_translation_sigma_m(X, noisy, np.zeros(3), np.zeros(3), K)
    assert pred.keypoints > 0.9 * len(X)  # a few share a z-buffer bin with a nearer point
    assert pred.image_sigma_m == pytest.approx(measured, rel=0.25)


def test_the_map_survives_its_file(recess, tmp_path):
    model, config = recess
    smap = scene_uncertainty_map(model, CAMERA, config=SceneUncertaintyConfig(cells=3, max_points=10**6))
    back = SceneUncertaintyMap.from_npz(smap.to_npz())
    np.testing.assert_array_equal(back.uncertainty, smap.uncertainty)
    np.testing.assert_array_equal(back.model.keypoints, model.keypoints)
    assert back.config == smap.config and back.n_directions == 5


# ----------------------------------------------------------------------------- the look it chooses
NARROW = PinholeCamera(fx=2400.0, fy=2400.0, cx=320.0, cy=240.0, width=640, height=480)  # +-7.6 deg across


class _TurnOnlySession:
    """Records the commanded flange motions; the camera turns with them (a perfect platform)."""

    def __init__(self, X: np.ndarray):
        self.X, self.motions = X, []
        self.timing = SimpleNamespace(wait_s=0.0, total_s=0.0)

    def move_by(self, M_flange: np.ndarray) -> float:
        self.motions.append(M_flange.copy())
        return 0.0


def _run(scene):
    from fgcd_cli.relocation.coarse.passive import View
    from fgcd_cli.relocation.coarse.stage import _CoarseRun
    from fgcd_cli.relocation.coarse.stage_inputs import CoarseInputs
    from fgcd_core.se3 import exp_se3
    from fgcd_core.sim3 import Sim3

    X = exp_se3(np.r_[0.03, -0.05, 0.12, np.radians([1.0, 2.0, 90.0])])
    session = _TurnOnlySession(X)
    ref = SimpleNamespace(points=_sheet(-1.0, 1.0, -0.5, 0.5, 1.5, 0.01), T_ref_camref=np.eye(4))
    run = _CoarseRun(
        CoarseInputs(
            session=session,
            reference=ref,
            ref_index=None,
            camera=NARROW,
            scale=1.0,
            T_flange_cam=X,
            init=Sim3(np.eye(3), np.zeros(3), 1.0),
            reference_images=None,
            grab_current=None,
            scene=scene,
        )
    )
    view = View(T_cur_cam=np.eye(4), notes={}, best=None, unverified=("3d", np.eye(4), None))
    assert run._look(1, view, None) is None
    return run, session, X


def test_the_look_turns_towards_the_lower_uncertainty_heading():
    # a flat wall at 1.5 m whose only texture lies left of the current view (negative yaw turns left)
    wall = _sheet(-1.0, 1.0, -0.5, 0.5, 1.5, 0.004)
    texture = wall[(wall[:, 0] < -0.15)][::3]
    model = SceneModel(
        points=wall,
        normals=np.tile([0.0, 0.0, -1.0], (len(wall), 1)),
        keypoints=texture,
        keypoint_image=np.zeros(len(texture), dtype=int),
        T_ref_camref=np.eye(4),
        centroid=np.array([0.0, 0.0, 1.5]),
    )
    config = SceneUncertaintyConfig(cells=1, extent_m=0.0, max_points=10**6)
    smap = scene_uncertainty_map(model, NARROW, config=config)
    u_right = view_uncertainty(model, camera_turn(math.radians(4.0), 0.0), NARROW, config=config)[0]
    u_left = view_uncertainty(model, camera_turn(math.radians(-4.0), 0.0), NARROW, config=config)[0]
    assert u_left < u_right  # the case makes the point: the fixed order would look right first
    run, session, X = _run(lambda: smap)
    step = run.steps[0]
    assert step.look["chosen_by"] == "scene uncertainty"
    assert step.look["yaw_deg"] < 0 and step.look["pitch_deg"] == 0
    assert step.look["uncertainty"] == min(c["uncertainty"] for c in step.look["candidates"])
    assert step.look["uncertainty"] == pytest.approx(u_left)
    # the turn-around action stays a pure rotation of the camera about its centre
    (M,) = session.motions
    M_cam = invert_pose(X) @ M @ X
    assert np.linalg.norm(M_cam[:3, 3]) < 1e-9
    assert pose_distance(np.eye(4), M_cam)[1] == pytest.approx(CoarseConfig().look_deg)


def test_without_a_map_the_look_keeps_the_fixed_order():
    run, session, _X = _run(None)
    assert run.steps[0].look == {
        "yaw_deg": pytest.approx(CoarseConfig().look_deg),
        "pitch_deg": 0.0,
        "chosen_by": "fixed order",
    }


# ----------------------------------------------------------------------------- the report
def _coarse_rows() -> list[dict]:
    """Two coarse steps as ``coarse.jsonl`` holds them: an unverified look, then a verified move."""
    return [
        {"step": 1, "action": "look", "source": "", "estimates": {"3d": {"position_refcam_m": [0.18, -0.05, 0.02]}}},
        {
            "step": 2,
            "action": "move",
            "source": "image",
            "estimates": {
                "3d": {"position_refcam_m": [0.0, 0.0, 0.0]},
                "image": {"position_refcam_m": [0.15, -0.04, 0.01]},
            },
        },
    ]


def test_the_report_shows_the_map_with_the_coarse_estimates(recess):
    import cv2

    from fgcd_cli.changes.detect import detect_changes
    from fgcd_cli.report.html import ReportContext, render_diff_report
    from fgcd_cli.report.scene_map import coarse_positions_mm

    model, _config = recess
    smap = scene_uncertainty_map(model, CAMERA, config=SceneUncertaintyConfig(cells=3, max_points=10**6))
    xyz, verified, steps = coarse_positions_mm(_coarse_rows())
    np.testing.assert_allclose(xyz, [[180.0, -50.0, 20.0], [150.0, -40.0, 10.0]])  # the estimate each step used
    assert verified.tolist() == [False, True] and steps == [1, 2]
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.random((96, 96)).astype(np.float32), (0, 0), 2)
    result = detect_changes([img], [img.copy()])
    with_map = render_diff_report(
        ref_image=img, cur_image=img, result=result, context=ReportContext(scene_map=smap, coarse_log=_coarse_rows())
    )
    assert 'alt="scene uncertainty map"' in with_map and "coarse stage estimated" in with_map
    without = render_diff_report(ref_image=img, cur_image=img, result=result, context=ReportContext())
    assert "scene uncertainty map" not in without


def test_the_map_is_computed_once_per_reference_and_never_overwritten(tmp_path, recess):
    from fgcd_cli.app.scene_uncertainty import cached_scene_uncertainty, station_scene_uncertainty

    model, _config = recess
    calls = []

    class _Station:  # the reference observation's parts the use case reads
        path = tmp_path

        def reference(self):
            return SimpleNamespace(
                manifest={"created": "2026-01-01"},
                image_names=lambda: [],
                array=lambda name: {"cloud_points": model.points, "cloud_intensities": None, "T_ref_camref": np.eye(4)}[
                    name
                ],
            )

    station = _Station()
    config = SceneUncertaintyConfig(cells=3)
    assert cached_scene_uncertainty(station) is None  # an old campaign: nothing cached, nothing computed
    first = station_scene_uncertainty(station, CAMERA, config=config, say=calls.append)
    (path,) = tmp_path.glob("scene_uncertainty-*.npz")
    stamp = path.stat().st_mtime_ns
    second = station_scene_uncertainty(station, CAMERA, config=config, say=calls.append)
    assert path.stat().st_mtime_ns == stamp and len(calls) == 1  # read back, not recomputed
    np.testing.assert_array_equal(first.uncertainty, second.uncertainty)
    assert cached_scene_uncertainty(station) is not None
    # other options: another file, the first one untouched
    station_scene_uncertainty(station, CAMERA, config=SceneUncertaintyConfig(cells=2), say=calls.append)
    assert len(list(tmp_path.glob("scene_uncertainty-*.npz"))) == 2 and path.stat().st_mtime_ns == stamp


def test_a_corner_pins_every_direction_for_the_3d_localizer():
    """Three orthogonal walls 0.6 m long meeting 0.6 m ahead: each translation and turn moves some wall
    along its normal by more than the model's cloud error (1 % of the depth) allows, so the 3D localizer
    succeeds (no texture: the image localizer cannot)."""
    s = np.arange(0.0, 0.6, 0.006)
    A, B = np.meshgrid(s, s)
    a, b = A.ravel(), B.ravel()
    corner = np.array([0.0, 0.0, 0.6])
    walls = [
        np.column_stack([a, b, np.zeros_like(a)]),
        np.column_stack([a, np.zeros_like(a), b]),
        np.column_stack([np.zeros_like(a), a, b]),
    ]
    normals = [np.tile(n, (len(a), 1)) for n in ([0, 0, 1.0], [0, 1.0, 0], [1.0, 0, 0])]
    # the corner opens towards the camera: walls at x, y, z >= 0 around it, turned to face the camera
    inward = np.ones(3) / math.sqrt(3.0)  # the corner's opening, in wall coordinates: towards the camera (-z)
    r1 = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)
    R = np.vstack([r1, np.cross(-inward, r1), -inward])
    assert np.linalg.det(R) == pytest.approx(1.0)
    points = np.vstack(walls) @ R.T + corner
    model = SceneModel(
        points=points,
        normals=np.vstack(normals) @ R.T,
        keypoints=np.zeros((0, 3)),
        keypoint_image=np.zeros(0, dtype=int),
        T_ref_camref=np.eye(4),
        centroid=corner,
    )
    pred = predict_view(model, np.eye(4), CAMERA, config=SceneUncertaintyConfig(max_points=10**6))
    assert pred.surface_points > 1000
    assert pred.weak_directions == 0 and pred.geometry_ok and not pred.image_ok


def test_a_reference_without_a_cloud_gives_no_map_and_says_why(tmp_path):
    from fgcd_cli.app.scene_uncertainty import station_scene_uncertainty
    from fgcd_cli.errors import CampaignError

    def missing(name):
        raise CampaignError(f"the reference has no array {name!r}")

    station = SimpleNamespace(
        path=tmp_path, reference=lambda: SimpleNamespace(manifest={}, array=missing, image_names=lambda: [])
    )
    said = []
    assert station_scene_uncertainty(station, CAMERA, say=said.append) is None
    assert len(said) == 1 and "fixed order" in said[0] and "cloud_points" in said[0]
    assert not list(tmp_path.glob("scene_uncertainty-*"))


def test_a_panel_that_is_one_value_everywhere_says_so():
    from fgcd_cli.report.scene_map import uniform_note

    assert uniform_note(np.zeros((3, 4))) == "\n(0% at every position)"
    assert uniform_note(np.full((3, 4), 0.25)) == "\n(25% at every position)"
    assert uniform_note(np.array([[0.0, 0.5]])) == ""  # a map that varies says where: no note
