"""ChArUco board and intrinsic calibration against simulated views with known intrinsics."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fgcd_cli.calibration.board import BoardSpec, load_board_sidecar, write_printable_board
from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.intrinsics import IntrinsicsResult, calibrate_intrinsics, coverage_feedback
from fgcd_cli.errors import UserInputError
from fgcd_core.camera import PinholeCamera
from fgcd_drivers.sim.board import BoardViewOptions, SimBoard, random_board_poses, render_board_view

CAM = dict(fx=620.0, fy=618.0, cx=322.0, cy=238.0, width=640, height=480)
DIST = (-0.12, 0.05, 0.001, -0.0005, 0.0)
SIM_BOARD = SimBoard()
SPEC = BoardSpec()


def _views(n, seed, dist=DIST, **pose_kw):
    poses = random_board_poses(SIM_BOARD, n, PinholeCamera(**CAM), rng=np.random.default_rng(seed), **pose_kw)
    return [
        render_board_view(
            SIM_BOARD,
            T,
            PinholeCamera(**CAM, dist=dist),
            options=BoardViewOptions(supersample=2),
            rng=np.random.default_rng(seed * 100 + i),
        )
        for i, T in enumerate(poses)
    ], poses


@pytest.fixture(scope="module")
def views():
    return _views(12, seed=3)


def test_rendered_corners_match_the_projection_of_the_true_board(views):
    # The renderer and the detector agree to a small fraction of a pixel, without bias.
    images, poses = views
    K = np.array([[CAM["fx"], 0, CAM["cx"]], [0, CAM["fy"], CAM["cy"]], [0, 0, 1.0]])
    offsets = []
    for image, T in zip(images[:4], poses[:4]):
        det = SPEC.detect(image)
        assert det.n_corners >= 8
        proj, _ = cv2.projectPoints(
            SPEC.corner_points()[det.ids], cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, np.array(DIST)
        )
        offsets.append(det.corners_px - proj.reshape(-1, 2))
    off = np.concatenate(offsets)
    assert np.all(np.abs(off.mean(axis=0)) < 0.03)
    assert np.sqrt(np.mean(off**2)) < 0.15


def test_calibration_recovers_true_intrinsics(views):
    images, _ = views
    result = calibrate_intrinsics(images, SPEC)
    cam = result.camera
    # Corner noise ~0.05 px over ~500 corners: focal length and principal point to well under 0.5 %.
    assert abs(cam.fx / CAM["fx"] - 1) < 0.005
    assert abs(cam.fy / CAM["fy"] - 1) < 0.005
    assert abs(cam.cx - CAM["cx"]) < 0.005 * CAM["fx"]
    assert abs(cam.cy - CAM["cy"]) < 0.005 * CAM["fy"]
    assert abs(cam.dist[0] - DIST[0]) < 0.01
    # OpenCV's standard deviations are consistent with the actual error.
    assert abs(cam.fx - CAM["fx"]) < 6 * result.std_px["fx"] + 0.05
    assert result.rms_px < 0.3
    assert result.n_views == 12 and not result.rejected
    back = IntrinsicsResult.from_dict(result.to_dict())
    assert back.camera == cam and back.per_view_error_px == result.per_view_error_px


def test_bad_views_are_rejected_with_reasons(views):
    images, _ = views
    blank = np.full_like(images[0], 120)
    # A view through a very different lens cannot fit the model: its error stands out.
    foreign, _ = _views(1, seed=9, dist=(0.6, 0.4, 0.0, 0.0, 0.0))
    names = [f"img{i}" for i in range(len(images))] + ["blank", "foreign"]
    result = calibrate_intrinsics(list(images) + [blank, foreign[0]], SPEC, names=names)
    assert result.rejected["blank"] == "board not found"
    assert "foreign" in result.rejected and "reprojection error" in result.rejected["foreign"]
    assert abs(result.camera.fx / CAM["fx"] - 1) < 0.005


def test_missing_board_is_a_clear_error():
    blank = [np.full((480, 640), 120, np.uint8)] * 5
    with pytest.raises(CalibrationError, match="found in only 0 of 5 images"):
        calibrate_intrinsics(blank, SPEC)


def test_bad_input_errors(views):
    images, _ = views
    with pytest.raises(UserInputError, match="same size"):
        calibrate_intrinsics([images[0], images[1][:-10]], SPEC)
    with pytest.raises(UserInputError, match="distortion model"):
        calibrate_intrinsics(images, SPEC, distortion_model="fisheye9")
    with pytest.raises(UserInputError, match="no calibration images"):
        calibrate_intrinsics([], SPEC)


def test_coverage_feedback_names_the_empty_regions():
    pts = np.array([[320.0, 240.0], [330.0, 250.0], [50.0, 400.0]])
    pct, feedback = coverage_feedback(pts, 640, 480)
    assert "move the board to the top-left corner of the image" in feedback
    assert not any("bottom-left" in f for f in feedback)
    assert not any("centre" in f for f in feedback)
    assert pct == pytest.approx(100 * 2 / 36)


def test_printable_board_png_and_pdf(tmp_path):
    board = BoardSpec(squares_x=8, squares_y=6, square_m=0.03, marker_m=0.022)
    side = write_printable_board(board, tmp_path / "b.png", dpi=200)
    data = (tmp_path / "b.png").read_bytes()
    assert b"pHYs" in data[:64]
    image = cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_GRAYSCALE)
    # 30 mm at 200 dpi = 236 px per square: the printed square differs by < half a pixel.
    assert abs(side["printed_square_mm"] - 30.0) < 0.5 * 25.4 / 200
    assert board.detect(image).n_corners == board.n_corners
    assert load_board_sidecar(tmp_path / "b.png.json") == board
    write_printable_board(board, tmp_path / "b.pdf")
    assert (tmp_path / "b.pdf").read_bytes().startswith(b"%PDF")
    with pytest.raises(UserInputError, match=".png or .pdf"):
        write_printable_board(board, tmp_path / "b.jpg")


def test_board_spec_validation():
    with pytest.raises(UserInputError, match="smaller than the square"):
        BoardSpec(square_m=0.02, marker_m=0.03)
    with pytest.raises(UserInputError, match="dictionary"):
        BoardSpec(dictionary="DICT_NOPE")
    with pytest.raises(UserInputError, match="do not fit"):
        BoardSpec(squares_x=20, squares_y=20, dictionary="DICT_4X4_50")


def test_an_uncertain_focal_length_asks_for_more_views():
    """OpenCV's focal sigma drives the hint: 6 views (~0.2 %) get it, 30 views (~0.055 %) do not."""
    few, _ = _views(6, seed=3)
    result = calibrate_intrinsics(few, SPEC)
    assert 100 * result.std_px["fx"] / result.camera.fx > 0.06
    assert any("focal length known to" in line for line in result.feedback)
    many, _ = _views(30, seed=4)
    result = calibrate_intrinsics(many, SPEC)
    assert 100 * result.std_px["fx"] / result.camera.fx < 0.06
    assert not any("focal length known to" in line for line in result.feedback)
