"""The target-free result refined on the images: ``X`` from the bundle adjustment, the scale re-estimated.

Starts from the rACR linear solution (:func:`fgcd_cli.calibration.handeye.linear.solve_handeye_scale`),
refines ``X`` on the images of the stops or of every rest pose of the path
(:func:`fgcd_cli.calibration.handeye.refine.refine_handeye_images`), then takes
the map scale from the VSE's map depths when its keyframes are given
(:func:`fgcd_cli.calibration.depth_scale.scale_from_depths`), else from its
camera motions with the refined ``X`` (docs/calibration.md, "Target-free").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from fgcd_cli.calibration.depth_scale import KeyframeDepths, scale_from_depths
from fgcd_cli.calibration.errors import CalibrationError
from fgcd_cli.calibration.handeye.linear import (
    HandEyeMethod,
    Regress,
    estimate_scale,
    pair_residuals,
    per_sample_residuals,
)
from fgcd_cli.calibration.handeye.refine import BAHandEyeResult, refine_handeye_images
from fgcd_cli.calibration.handeye.tracks import MatchConfig
from fgcd_cli.calibration.samples import relative_motions
from fgcd_core.camera import PinholeCamera

__all__ = ["PathViews", "TargetFreeConfig", "ScaleMethod", "refine_target_free"]

#: What the refinement record says it did (stored in ``handeye.json``).
REFINEMENT_TEXT = (
    "bundle adjustment of X over the images of the platform's rest poses, camera poses = T_base_flange @ X"
)


class ScaleMethod(StrEnum):
    """Where the refined map scale came from (the ``scale_method`` of the refinement record)."""

    MOTIONS = "camera motions (estimate_scale, regress=vse)"
    DEPTHS = "map depths (scale_from_depths)"


@dataclass(frozen=True, kw_only=True)
class TargetFreeConfig:
    """Options of :func:`refine_target_free`.

    Attributes
    ----------
    n_features : int
        SIFT features per image.
    match_window : int
        Along the path, each view is matched with the next ``match_window`` views
        (the stops with each other).
    """

    n_features: int = 1500
    match_window: int = 2


@dataclass(frozen=True, kw_only=True)
class PathViews:
    """Every pose the platform came to rest at during a procedure, in order, with its image.

    The steps between the stops (a few millimetres and a degree apart) are views
    with a reported flange pose like the stops: the bundle adjustment needs no
    VSE pose for them. Each step brings the platform's repeatability error anew,
    and with ~10x more views than stops the adjustment averages it down
    (docs/calibration.md §3).

    Attributes
    ----------
    T_base_flange : list of (4, 4) ndarray
        Reported flange pose of each view, metres.
    images : list of images
        The camera image at each view (undistorted like the stop images).
    stop_index : list of int
        For each stop sample (in the order of the samples), its index in this path.
    """

    T_base_flange: list
    images: list
    stop_index: list


def refine_target_free(
    linear,
    T_base_flange: Sequence[np.ndarray],
    T_map_cam: Sequence[np.ndarray],
    images: Sequence[np.ndarray],
    camera: PinholeCamera,
    *,
    keyframes: Sequence[KeyframeDepths] | None = None,
    path: PathViews | None = None,
    config: TargetFreeConfig | None = None,
):
    """The target-free result with ``X`` refined on the stop images and the scale re-estimated.

    Parameters
    ----------
    linear : HandEyeResult
        The rACR linear solution of the same samples; its ``X`` starts the refinement.
    T_base_flange, T_map_cam : sequences of N (4, 4) ndarray
        The samples (reported flange poses, VSE camera poses in map units).
    images : sequence of N images
        Camera image at each stop.
    camera : PinholeCamera
        Intrinsics of the images (zero distortion for undistorted images).
    keyframes : sequence of KeyframeDepths, optional
        The VSE's keyframes with their cloud; when given (and matched), the scale
        is the ratio of metric to map depths (:func:`scale_from_depths`).
    path : PathViews, optional
        All the views along the platform's path (stops included); when given, the
        adjustment runs over them instead of over the stops alone.
    config : TargetFreeConfig, optional
        Features and matching window (default: :class:`TargetFreeConfig`).

    Returns
    -------
    HandEyeResult
        Method ``"racr-linear+image-ba"``; ``scale`` from the map depths when
        ``keyframes`` are given, else from the VSE's camera motions with the refined
        ``X`` (:func:`fgcd_cli.calibration.handeye.linear.estimate_scale`); residuals
        recomputed; ``refinement`` says what was done.

    Raises
    ------
    CalibrationError
        The images could not be matched (the caller keeps the linear result).
    """
    config = config or TargetFreeConfig()
    K, dist = camera.K, camera.dist
    ba, views, stop_rms = _adjust(linear, T_base_flange, images, K, dist, path, config)
    # the VSE side carries the noise: fit 1/s (unbiased for independent pose noise, see estimate_scale)
    sc = estimate_scale(ba.T_flange_cam, T_base_flange, T_map_cam, pairs=linear.pairs, regress=Regress.VSE)
    scale, scale_method, depth_info = _depth_scale(ba, keyframes, K, sc.scale)
    MB = relative_motions(list(T_base_flange), linear.pairs)
    MA = relative_motions(list(T_map_cam), linear.pairs)
    MA_metric = [np.block([[A[:3, :3], scale * A[:3, 3:4]], [A[3:4, :]]]) for A in MA]
    res_mm, res_deg = pair_residuals(ba.T_flange_cam, MB, MA_metric)
    refinement = {
        **_ba_record(ba, views, stop_rms),
        "linear_T_flange_cam": np.asarray(linear.T_flange_cam).tolist(),
        "linear_scale": linear.scale,
        "scale_method": str(scale_method),
        "scale_from_motions": sc.scale,
        "scale_std": sc.scale_std,
        **depth_info,
    }
    n = linear.n_samples
    return replace(
        linear,
        T_flange_cam=ba.T_flange_cam,
        scale=scale,
        method=str(HandEyeMethod.RACR_LINEAR_IMAGE_BA),
        residuals_mm=res_mm,
        residuals_deg=res_deg,
        sample_residuals_mm=per_sample_residuals(n, linear.pairs, res_mm),
        sample_residuals_deg=per_sample_residuals(n, linear.pairs, res_deg),
        notes=list(linear.notes) + list(ba.notes),
        refinement=refinement,
    )


def _depth_scale(
    ba: BAHandEyeResult, keyframes: Sequence[KeyframeDepths] | None, K: np.ndarray, motions_scale: float
) -> tuple[float, ScaleMethod, dict]:
    """The scale from the map depths when keyframes are given and match, else ``motions_scale``; with its record."""
    if not keyframes:
        return motions_scale, ScaleMethod.MOTIONS, {}
    try:
        d_scale, d_spread, d_n = scale_from_depths(ba.points_base, ba.T_flange_cam, keyframes, K)
    except CalibrationError as exc:
        return motions_scale, ScaleMethod.MOTIONS, {"scale_depth_error": str(exc)}
    return d_scale, ScaleMethod.DEPTHS, {"scale_depth_spread": d_spread, "scale_depth_matches": d_n}


def _adjust(
    linear, T_base_flange, images, K, dist, path: PathViews | None, config: TargetFreeConfig
) -> tuple[BAHandEyeResult, int, np.ndarray]:
    """The bundle adjustment over the path's views when given (else the stops); ``(result, views, stop RMS)``."""
    if path is not None and len(path.images) > len(images):
        if len(path.stop_index) != len(images) or len(path.T_base_flange) != len(path.images):
            raise CalibrationError("the path views do not match the stop samples")
        match = MatchConfig(
            n_features=config.n_features,
            match_window=config.match_window,
            anchors=tuple(int(a) for a in path.stop_index),
        )
        ba = refine_handeye_images(path.T_base_flange, path.images, K, linear.T_flange_cam, dist=dist, match=match)
        return ba, len(path.images), np.asarray(ba.per_image_rms_px)[list(path.stop_index)]
    ba = refine_handeye_images(
        T_base_flange, images, K, linear.T_flange_cam, dist=dist, match=MatchConfig(n_features=config.n_features)
    )
    return ba, len(images), np.asarray(ba.per_image_rms_px)


def _ba_record(ba: BAHandEyeResult, views: int, stop_rms: np.ndarray) -> dict:
    """The adjustment's part of the refinement record."""
    return {
        "method": REFINEMENT_TEXT,
        "views": views,
        "points": ba.n_points,
        "observations": ba.n_observations,
        "rms_px": ba.rms_px,
        "per_image_rms_px": stop_rms.tolist(),
        "std_mm": ba.std_mm,
        "std_deg": ba.std_deg,
        "platform_rotation_scale": ba.rotation_scale,
        "platform_rotation_scale_std": ba.rotation_scale_std,
        "change_mm": ba.change_mm,
        "change_deg": ba.change_deg,
    }
