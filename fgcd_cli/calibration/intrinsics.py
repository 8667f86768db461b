"""Camera intrinsics from ChArUco board views.

Steps: detect the board's corners in every image (``cv2.aruco.CharucoDetector``),
reject views with too few or collinear corners, calibrate with
``cv2.calibrateCameraExtended`` (per-view RMS errors and parameter standard
deviations), drop views whose error is far above the others and calibrate
again, then tell the user what the views lack: image regions the board never
reached, and missing tilt (without tilted views the focal length is weakly
determined).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import cv2
import numpy as np

from fgcd_cli.calibration.board import BoardDetection, BoardSpec
from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.result import utc_now
from fgcd_cli.errors import UserInputError
from fgcd_core.camera import PinholeCamera

__all__ = ["IntrinsicsResult", "DistortionModel", "calibrate_intrinsics", "DISTORTION_MODELS", "coverage_feedback"]


class DistortionModel(StrEnum):
    """Lens distortion models (the coefficients estimated)."""

    NONE = "none"
    K1K2 = "k1k2"
    K1K2P1P2 = "k1k2p1p2"
    K1K2P1P2K3 = "k1k2p1p2k3"


#: Distortion models: name -> OpenCV flags. PinholeCamera carries (k1, k2, p1, p2, k3).
DISTORTION_MODELS: dict[str, int] = {
    DistortionModel.NONE: cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    DistortionModel.K1K2: cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    DistortionModel.K1K2P1P2: cv2.CALIB_FIX_K3,
    DistortionModel.K1K2P1P2K3: 0,
}

#: Fewest corners for a view to count (a homography needs 4; margin for noise).
MIN_CORNERS_PER_VIEW = 8
#: Fewest usable views.
MIN_VIEWS = 4
_REGION_NAMES = {
    (0, 0): "top-left corner",
    (1, 0): "top edge",
    (2, 0): "top-right corner",
    (0, 1): "left edge",
    (1, 1): "centre",
    (2, 1): "right edge",
    (0, 2): "bottom-left corner",
    (1, 2): "bottom edge",
    (2, 2): "bottom-right corner",
}


@dataclass(frozen=True, kw_only=True)
class IntrinsicsResult:
    """Calibrated camera and the evidence for it.

    Attributes
    ----------
    camera : PinholeCamera
        Intrinsics and distortion.
    distortion_model : str
        One of :data:`DISTORTION_MODELS`.
    rms_px : float
        Overall RMS reprojection error of the kept views, pixels.
    per_view_error_px : dict of str to float
        RMS reprojection error per kept view (by image name), pixels.
    rejected : dict of str to str
        Views not used, with the reason.
    n_views : int
        Views used.
    n_corners : int
        Corners used over all views.
    std_px : dict of str to float
        One-sigma uncertainty of fx, fy, cx, cy (pixels) from OpenCV.
    coverage_pct : float
        Share of a 6 x 6 grid of image cells that saw at least one corner.
    max_tilt_deg : float
        Largest angle between the board normal and the optical axis over the views.
    feedback : list of str
        What to do next ("move the board to the top-left corner").
    board : dict
        The board geometry used.
    created_utc : str
    """

    camera: PinholeCamera
    distortion_model: str
    rms_px: float
    per_view_error_px: dict[str, float]
    rejected: dict[str, str]
    n_views: int
    n_corners: int
    std_px: dict[str, float]
    coverage_pct: float
    max_tilt_deg: float
    feedback: list[str]
    board: dict
    created_utc: str = field(default_factory=utc_now)

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "kind": "intrinsics",
            "camera": self.camera.to_dict(),
            "K": self.camera.K.tolist(),
            "distortion_model": self.distortion_model,
            "rms_px": self.rms_px,
            "per_view_error_px": dict(self.per_view_error_px),
            "rejected": dict(self.rejected),
            "n_views": self.n_views,
            "n_corners": self.n_corners,
            "std_px": dict(self.std_px),
            "coverage_pct": self.coverage_pct,
            "max_tilt_deg": self.max_tilt_deg,
            "feedback": list(self.feedback),
            "board": dict(self.board),
            "created_utc": self.created_utc,
        }

    @classmethod
    def from_dict(cls, data: dict) -> IntrinsicsResult:
        """Inverse of :meth:`to_dict`."""
        return cls(
            camera=PinholeCamera.from_dict(data["camera"]),
            distortion_model=str(data["distortion_model"]),
            rms_px=float(data["rms_px"]),
            per_view_error_px={k: float(v) for k, v in data.get("per_view_error_px", {}).items()},
            rejected=dict(data.get("rejected", {})),
            n_views=int(data["n_views"]),
            n_corners=int(data.get("n_corners", 0)),
            std_px={k: float(v) for k, v in data.get("std_px", {}).items()},
            coverage_pct=float(data.get("coverage_pct", float("nan"))),
            max_tilt_deg=float(data.get("max_tilt_deg", float("nan"))),
            feedback=list(data.get("feedback", [])),
            board=dict(data.get("board", {})),
            created_utc=str(data.get("created_utc", "")),
        )


#: Above this one-sigma focal uncertainty (percent) the result suggests more views: a focal
#: error of a few tenths of a percent already moves a target-free hand-eye by millimetres
#: (docs/calibration.md, "2. Camera intrinsics"; the measurements are in docs/lab/2026-11-22-calibrate.md,
#: "2026-11-25: the bias explained, the target met").
FOCAL_STD_HINT_PCT = 0.06


def coverage_feedback(corners_px: np.ndarray, width: int, height: int) -> tuple[float, list[str]]:
    """Which image regions the board never reached.

    Parameters
    ----------
    corners_px : (M, 2) ndarray
        All detected corners of all kept views, pixels.
    width, height : int
        Image size.

    Returns
    -------
    coverage_pct : float
        Share of a 6 x 6 grid of cells holding at least one corner, percent.
    feedback : list of str
        One line per 3 x 3 region with no corner ("move the board to the top-left corner").
    """
    pts = np.asarray(corners_px, dtype=float).reshape(-1, 2)
    fine = np.zeros((6, 6), dtype=bool)
    coarse = np.zeros((3, 3), dtype=int)
    if len(pts):
        gx = np.clip((pts[:, 0] / width * 6).astype(int), 0, 5)
        gy = np.clip((pts[:, 1] / height * 6).astype(int), 0, 5)
        fine[gy, gx] = True
        np.add.at(coarse, (np.clip(gy // 2, 0, 2), np.clip(gx // 2, 0, 2)), 1)
    feedback = [
        f"move the board to the {_REGION_NAMES[(cx, cy)]} of the image"
        for cy in range(3)
        for cx in range(3)
        if coarse[cy, cx] == 0
    ]
    return float(fine.mean() * 100.0), feedback


def _image_size(images: Sequence[np.ndarray]) -> tuple[int, int]:
    sizes = {tuple(np.asarray(im).shape[:2]) for im in images}
    if len(sizes) != 1:
        raise UserInputError(f"all calibration images must have the same size, found {sorted(sizes)}")
    h, w = sizes.pop()
    return int(w), int(h)


def calibrate_intrinsics(
    images: Sequence[np.ndarray],
    board: BoardSpec,
    *,
    names: Sequence[str] | None = None,
    distortion_model: str = "k1k2p1p2",
    max_view_error_factor: float = 3.0,
    max_view_error_px: float = 2.0,
) -> IntrinsicsResult:
    """Calibrate a camera from images of a ChArUco board.

    Parameters
    ----------
    images : sequence of (H, W) or (H, W, 3) ndarray
        Views of the board (uint8, or float in [0, 1]); all the same size.
    board : BoardSpec
        The board as printed (measure the square!).
    names : sequence of str, optional
        Names for the per-view report (default ``view_000``...).
    distortion_model : str
        One of :data:`DISTORTION_MODELS`; ``k1k2p1p2`` suits most lenses,
        ``k1k2p1p2k3`` wide-angle lenses with views reaching the image corners.
    max_view_error_factor, max_view_error_px : float
        A view is rejected after the first calibration if its RMS error exceeds
        both ``factor * median`` and ``max_view_error_px`` (motion blur, a bent board).

    Returns
    -------
    IntrinsicsResult

    Raises
    ------
    UserInputError
        Unknown distortion model, no images, mixed image sizes.
    CalibrationError
        The board was found in fewer than 4 views.
    """
    if distortion_model not in DISTORTION_MODELS:
        raise UserInputError(
            f"unknown distortion model '{distortion_model}'; choose from {', '.join(DISTORTION_MODELS)}"
        )
    if len(images) == 0:
        raise UserInputError("no calibration images given")
    names = [f"view_{i:03d}" for i in range(len(images))] if names is None else list(names)
    if len(names) != len(images):
        raise UserInputError("one name per image is needed")
    width, height = _image_size(images)
    kept, rejected = _detect_views(images, names, board)
    flags = DISTORTION_MODELS[distortion_model]
    fit = _calibrate(kept, board, (width, height), flags)
    errors = fit["per_view"]
    threshold = max(max_view_error_factor * float(np.median(errors)), max_view_error_px)
    bad = [i for i, e in enumerate(errors) if e > threshold]
    if bad and len(kept) - len(bad) >= MIN_VIEWS:
        for i in bad:
            rejected[kept[i][0]] = (
                f"reprojection error {errors[i]:.2f} px above {threshold:.2f} px (blur or bent board?)"
            )
        kept = [kv for i, kv in enumerate(kept) if i not in set(bad)]
        fit = _calibrate(kept, board, (width, height), flags)

    K, dist = fit["K"], fit["dist"]
    d5 = tuple(float(v) for v in (list(np.ravel(dist)[:5]) + [0.0] * 5)[:5])
    camera = PinholeCamera.from_K(K, width, height, d5)
    all_corners = np.concatenate([det.corners_px for _, det in kept])
    coverage_pct, feedback = coverage_feedback(all_corners, width, height)
    max_tilt = max(math.degrees(math.acos(min(1.0, abs(float(cv2.Rodrigues(r)[0][2, 2]))))) for r in fit["rvecs"])
    feedback += _fit_feedback(fit, len(kept), max_tilt)
    std = fit["std"]
    return IntrinsicsResult(
        camera=camera,
        distortion_model=distortion_model,
        rms_px=float(fit["rms"]),
        per_view_error_px={name: float(e) for (name, _), e in zip(kept, fit["per_view"])},
        rejected=rejected,
        n_views=len(kept),
        n_corners=int(len(all_corners)),
        std_px={"fx": float(std[0]), "fy": float(std[1]), "cx": float(std[2]), "cy": float(std[3])},
        coverage_pct=coverage_pct,
        max_tilt_deg=float(max_tilt),
        feedback=feedback,
        board=board.to_dict(),
    )


def _detect_views(
    images: Sequence[np.ndarray], names: list[str], board: BoardSpec
) -> tuple[list[tuple[str, BoardDetection]], dict[str, str]]:
    """The views with enough non-collinear corners, and the others with the reason.

    Raises
    ------
    CalibrationError
        Fewer than :data:`MIN_VIEWS` views kept.
    """
    cv_board = board.cv_board()
    rejected: dict[str, str] = {}
    kept: list[tuple[str, BoardDetection]] = []
    for name, image in zip(names, images):
        det = board.detect(image)
        if det.n_corners == 0:
            rejected[name] = "board not found"
            continue
        if det.n_corners < MIN_CORNERS_PER_VIEW:
            rejected[name] = f"only {det.n_corners} corners (need {MIN_CORNERS_PER_VIEW})"
            continue
        if cv_board.checkCharucoCornersCollinear(det.ids.reshape(-1, 1).astype(np.int32)):
            rejected[name] = "corners are collinear (only one row of the board visible)"
            continue
        kept.append((name, det))
    if len(kept) < MIN_VIEWS:
        raise CalibrationError(
            f"the board was found in only {len(kept)} of {len(images)} images (need at least {MIN_VIEWS}, "
            "15-30 is a good target): check the board description (squares, dictionary) and the lighting"
        )
    return kept, rejected


def _fit_feedback(fit: dict, n_views: int, max_tilt: float) -> list[str]:
    """What the views lack beyond coverage: tilt, number, sharpness, a well-determined focal length."""
    feedback = []
    if max_tilt < 20.0:
        feedback.append(
            f"tilt the board more (largest tilt {max_tilt:.0f} deg): views at 20-45 deg fix the focal length"
        )
    if n_views < 12:
        feedback.append(f"only {n_views} good views: 15-30 give a stable result")
    if fit["rms"] > 1.0:
        feedback.append(f"RMS error {fit['rms']:.2f} px is high: check focus, motion blur and board flatness")
    K, std = fit["K"], fit["std"]
    focal_std_pct = 100.0 * max(float(std[0]) / float(K[0, 0]), float(std[1]) / float(K[1, 1]))
    if focal_std_pct > FOCAL_STD_HINT_PCT:
        # a focal error eps moves a target-free hand-eye by ~eps x the scene distance (docs/calibration.md §3)
        feedback.append(
            f"focal length known to +-{focal_std_pct:.2f} % (1 sigma); a target-free hand-eye inherits ~1 mm per "
            f"0.1 % at 0.6 m: add views tilted 30-45 deg in several directions"
        )
    return feedback


def _calibrate(kept: list[tuple[str, BoardDetection]], board: BoardSpec, size: tuple[int, int], flags: int) -> dict:
    obj = board.corner_points()
    object_points = [obj[det.ids].astype(np.float32).reshape(-1, 1, 3) for _, det in kept]
    image_points = [det.corners_px.astype(np.float32).reshape(-1, 1, 2) for _, det in kept]
    try:
        rms, K, dist, rvecs, tvecs, std_int, _std_ext, per_view = cv2.calibrateCameraExtended(
            object_points, image_points, size, None, None, flags=flags
        )
    except cv2.error as exc:
        raise CalibrationError(f"OpenCV calibration failed: {str(exc).strip().splitlines()[-1]}") from exc
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0:
        raise CalibrationError("calibration diverged: add views with the board tilted and in the image corners")
    return {
        "rms": float(rms),
        "K": K,
        "dist": dist,
        "rvecs": rvecs,
        "tvecs": tvecs,
        "std": np.ravel(std_int)[:4],
        "per_view": np.ravel(per_view).astype(float),
    }
