"""Final image-based refinement: the last millimetres from the reference images themselves.

Why this stage exists. The rACR loop (3D alignment of the two VSE clouds) is
robust to lighting, but its accuracy is bounded by the two monocular clouds'
own distortions: two monocular sessions place their camera relative to their
cloud only to about 1 % of the depth (bas-relief ambiguity of few-cm motions),
which can leave pixels of true AFD while the loop's own estimate says a
fraction of one (``docs/relocation.md``, "Final image stage").

Once the loop has converged, the camera is within a few pixels of the
reference view, which is where feature matching *across lightings* works best
(no scale or perspective change, only shading). This stage matches the current
image against each reference image (SIFT, ratio test: the authors' own FDF
protocol; under a strong lighting change, the lighting-robust grid variant of
:mod:`fgcd_cli.metrics.afd`), lifts the reference keypoints to 3D with the reference cloud's depth
(points on each keypoint's ray, so a depth error only scales the correction),
and solves PnP with RANSAC (:mod:`fgcd_cli.relocation.image.pnp_fit`) for the current camera relative
to the reference camera. The motion it gives has the reference pose as an exact fixed point,
whatever the clouds' distortions. It acts only when the evidence is strong
(enough inliers, small reprojection error, a small motion, or a larger one
only on many more inliers); otherwise the rACR result stands and the log says
why. The same measurement is the loop's fallback when the 3D alignment pauses
on geometry it cannot register (a flat wall, a body of revolution).

Inputs are only what a real rig gives: images, the reference observation's
cloud and camera pose, the calibrated intrinsics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from fgcd_cli.changes.images import to_float_image, to_gray
from fgcd_cli.errors import FgcdError, UserInputError
from fgcd_cli.metrics.afd import FdfConfig, compute_fdf
from fgcd_cli.relocation.adjustment import clamp_motion
from fgcd_cli.relocation.image.pnp_fit import PnpFit, pnp_fit
from fgcd_cli.relocation.image.reference_depth import lift_reference_pixels
from fgcd_core.imaging import clahe, match_sift, to_gray_f32, to_gray_u8
from fgcd_core.se3 import pose_distance

__all__ = [
    "CROSS_LIGHT_COMMON_PX",
    "SAME_LIGHT_COMMON_PX",
    "ImageRefineConfig",
    "ImageRefinement",
    "local_contrast",
    "reference_keypoints_3d",
    "refine_from_reference_image",
]


#: The registration error every match of one image pair shares (pixels, per axis), under the reference's
#: own light and across lightings: each measured on real photographs with ``fgcd bench lighting``'s protocol
#: (the figures: docs/relocation.md, "Stop rules", Uncertainties). Used by the PnP uncertainty.
SAME_LIGHT_COMMON_PX = 0.15
CROSS_LIGHT_COMMON_PX = 1.0


@dataclass(frozen=True, kw_only=True)
class ImageRefineConfig:
    """Options of :func:`refine_from_reference_image`."""

    ratio: float = 0.75
    """Lowe ratio of the SIFT matching."""
    max_features: int = 4000
    """Strongest SIFT keypoints kept per image."""
    ransac_px: float = 2.0
    """PnP RANSAC reprojection threshold, pixels."""
    min_inliers: int = 40
    """Fewer SIFT PnP inliers than this: no trustworthy correction."""
    grid_cells: int = 12
    grid_patch_px: int = 64
    min_grid_inliers: int = 20
    """Fewer agreeing grid cells than this: no trustworthy correction."""
    min_inlier_ratio: float = 0.25
    max_rms_px: float = 1.0
    """Largest RMS reprojection error of the inliers after refinement."""
    common_error_px: float = CROSS_LIGHT_COMMON_PX
    """The error every match shares (pixels per axis): :data:`CROSS_LIGHT_COMMON_PX` unless the current
    image is taken under the reference image's own light (:data:`SAME_LIGHT_COMMON_PX`)."""
    depth_search_px: float = 6.0
    """A keypoint takes the depth of the reference points projected within this radius
    (front-most layer, inverse-distance weighted); the semi-dense cloud holds
    high-gradient pixels, not necessarily the keypoints'. A depth error only
    scales the correction, whose fixed point (the reference pose) stays exact."""
    max_motion_m: float = 0.02
    max_motion_deg: float = 1.5
    """Largest correction trusted on ordinary evidence (the last millimetres)."""
    strong_min_inliers: int = 100
    strong_min_inlier_ratio: float = 0.5
    strong_max_motion_m: float = 0.10
    strong_max_motion_deg: float = 5.0
    """A larger correction, up to these limits, is trusted only on strong
    evidence: at least ``strong_min_inliers`` PnP inliers making at least
    ``strong_min_inlier_ratio`` of the matches (a chance PnP fit on repeated or
    weak texture gathers neither). Beyond them, a correction on strong evidence
    is returned refused but ``oversize`` with its motion: the loop trusts it only
    when the 3D geometry of the same view confirms it
    (:mod:`fgcd_cli.relocation.image.cross_check`). The loop still clamps each motion to
    its largest step and measures again after moving."""


@dataclass(frozen=True, kw_only=True)
class ImageRefinement:
    """Outcome of one image-based refinement.

    Attributes
    ----------
    ok : bool
        True when ``M_cam`` can be trusted.
    reason : str
        "ok" or why not.
    M_cam : (4, 4) ndarray or None
        Camera motion to the reference pose, in the current camera frame
        (the reference camera's pose seen from the current camera), metres.
    measured_afd_px : float
        Mean displacement of the inlier matches between the reference and the
        current image (the paper's AFD, measured by matching).
    matches, inliers : int
        Ratio-test matches with a depth, PnP inliers.
    rms_px : float
        RMS reprojection error of the inliers.
    reference_image : str
        Name of the reference image that gave the most inliers.
    matcher : str
    """

    ok: bool
    reason: str
    M_cam: np.ndarray | None
    measured_afd_px: float
    matches: int
    inliers: int
    rms_px: float
    reference_image: str = ""
    matcher: str = ""
    """"sift" or "grid" (phase correlation of gradient-orientation patches)."""
    offset_sigma_mm: float = math.nan
    """1-sigma uncertainty of the camera position this correction implies, mm: the RMS
    radius ``sqrt(trace(Cov_t))`` of the PnP translation's covariance (see
    :func:`~fgcd_cli.relocation.image.pnp_uncertainty.pnp_translation_sigma_m`). NaN when no PnP
    solution was found."""
    oversize: bool = False
    """Refused only for its size: strong evidence, a correction beyond ``strong_max_motion_*``.
    ``M_cam`` and ``offset_sigma_mm`` are kept so that an independent check may confirm it."""
    unverified: bool = False
    """Refused only for its size on ordinary evidence: a correction beyond ``max_motion_*`` (up to
    ``strong_max_motion_*``) without the strong evidence. ``M_cam``, ``offset_sigma_mm`` and ``step_M_cam`` are
    kept so that the loop may approach it by one ordinary step and let the next measurement corroborate it
    (:mod:`fgcd_cli.relocation.image.probe`)."""
    step_M_cam: np.ndarray | None = None
    """With ``unverified``: ``M_cam`` shortened along its geodesic to ``max_motion_*`` (the largest motion
    ordinary evidence moves), (4, 4), metres."""


def reference_keypoints_3d(
    *,
    reference_images: dict[str, np.ndarray],
    camera,
    ref_points: np.ndarray,
    T_ref_camref: np.ndarray,
    config: ImageRefineConfig = ImageRefineConfig(),
) -> list[np.ndarray]:
    """The reference keypoints the image localizer can match, lifted to 3D, per reference image.

    The same detection (SIFT on the locally equalised image, ``config.max_features``) and lifting
    (:func:`lift_reference_pixels`) as :func:`refine_from_reference_image`.

    Returns
    -------
    list of (K_i, 3) ndarray
        One array per reference image (in ``reference_images`` order), ``ref`` frame, metres.
    """
    from fgcd_core.imaging import sift_features

    T = np.asarray(T_ref_camref, dtype=float)
    out = []
    for name, img in reference_images.items():
        gray = to_gray(to_float_image(img, name=f"reference image {name!r}"))
        xy, _desc = sift_features(_local_contrast_u8(gray), n_features=config.max_features)
        X, _has = lift_reference_pixels(
            xy, ref_points=ref_points, T_ref_camref=T, camera=camera, radius_px=config.depth_search_px
        )
        out.append(X @ T[:3, :3].T + T[:3, 3])
    return out


def refine_from_reference_image(
    *,
    reference_images: dict[str, np.ndarray],
    current_image: np.ndarray,
    camera,
    ref_points: np.ndarray,
    T_ref_camref: np.ndarray,
    config: ImageRefineConfig = ImageRefineConfig(),
) -> ImageRefinement:
    """The camera motion to the reference pose from the reference images and cloud.

    Parameters
    ----------
    reference_images : dict of name -> (H, W) ndarray
        Undistorted reference images (one per lighting), grey in [0, 1] or uint8.
    current_image : (H, W) ndarray
        Undistorted current image, same intrinsics.
    camera : PinholeCamera
        Pinhole intrinsics of both images (no distortion).
    ref_points : (N, 3) ndarray
        Reference cloud, metres, ``ref`` frame.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose in the ``ref`` frame.

    Returns
    -------
    ImageRefinement
    """

    def refused(reason: str, name: str = "") -> ImageRefinement:
        return ImageRefinement(
            ok=False,
            reason=reason,
            M_cam=None,
            measured_afd_px=math.nan,
            matches=0,
            inliers=0,
            rms_px=math.nan,
            reference_image=name,
        )

    try:
        cur = to_gray(to_float_image(current_image, name="current image"))
    except UserInputError as exc:
        return refused(str(exc))
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]], dtype=float)
    best: ImageRefinement | None = None
    for name, img in reference_images.items():
        try:
            ref = to_gray(to_float_image(img, name=f"reference image {name!r}"))
        except UserInputError as exc:
            res = refused(str(exc), name)
        else:
            if ref.shape != cur.shape:
                res = refused(f"reference image {name!r} is {ref.shape}, current {cur.shape}", name)
            else:
                res = _refine_one(
                    ref,
                    cur,
                    _ReferenceView(
                        K=K, camera=camera, ref_points=ref_points, T_ref_camref=T_ref_camref, config=config, name=name
                    ),
                )
        if best is None or (res.ok, res.inliers) > (best.ok, best.inliers):
            best = res
    return best if best is not None else refused("no reference image")


def local_contrast(gray: np.ndarray, *, clip_limit: float = 3.0, tiles: int = 8) -> np.ndarray:
    """Contrast-limited adaptive histogram equalisation (OpenCV CLAHE) of a grey image.

    Parameters
    ----------
    gray : (H, W) ndarray
        Grey image in [0, 1].

    Returns
    -------
    (H, W) float32 ndarray in [0, 1]

    Why: SIFT's detector drops extrema below a fixed contrast (0.04 of the
    range), which dim, low-contrast stone under a side light barely reaches;
    equalised locally, the same pair of views gives tens of times more matches,
    nearly all of them epipolar inliers (docs/lab/2026-11-25-code-comment-measurements.md, "Relocation").
    """
    return to_gray_f32(_local_contrast_u8(gray, clip_limit=clip_limit, tiles=tiles))


def _local_contrast_u8(gray: np.ndarray, *, clip_limit: float = 3.0, tiles: int = 8) -> np.ndarray:
    """:func:`local_contrast` as 8-bit levels, (H, W) uint8 (what SIFT detects on)."""
    return clahe(to_gray_u8(np.asarray(gray, dtype=np.float32)), clip_limit=float(clip_limit), tiles=int(tiles))


@dataclass(frozen=True, kw_only=True)
class _ReferenceView:
    """One reference image's geometry: the pinhole matrix ``K`` (3, 3), the camera, the reference cloud
    (N, 3) metres, the reference camera pose (4, 4), the options and the image's name."""

    K: np.ndarray
    camera: object
    ref_points: np.ndarray
    T_ref_camref: np.ndarray
    config: ImageRefineConfig
    name: str


def _refine_one(ref, cur, view: _ReferenceView) -> ImageRefinement:
    config = view.config
    p_ref, p_cur = match_sift(
        _local_contrast_u8(ref), _local_contrast_u8(cur), ratio=config.ratio, max_features=config.max_features
    )
    sift = _refine_matches(p_ref, p_cur, view, matcher="sift", min_inliers=config.min_inliers)
    if sift.ok or sift.oversize:
        return sift
    # Strong lighting change (another sun): lighting-robust grid correspondences
    # (phase correlation of gradient-orientation patches, the FDF grid variant).
    try:
        fdf = compute_fdf(
            ref,
            cur,
            config=FdfConfig(method="grid", grid_cells=config.grid_cells, patch_px=config.grid_patch_px, ransac_px=3.0),
        )
    except FgcdError as exc:
        return _replace_reason(sift, f"{sift.reason}; grid: {exc}")
    grid = _refine_matches(fdf.points_ref, fdf.points_cur, view, matcher="grid", min_inliers=config.min_grid_inliers)
    return grid if grid.ok else _replace_reason(sift, f"SIFT: {sift.reason}; grid: {grid.reason}")


def _replace_reason(res: ImageRefinement, reason: str) -> ImageRefinement:
    return replace(res, reason=reason)


def _refine_matches(p_ref, p_cur, view: _ReferenceView, *, matcher: str, min_inliers: int) -> ImageRefinement:
    """PnP of matched pixels ``p_ref`` (reference image) and ``p_cur`` (current image), (M, 2) each."""
    K, camera, config, name = view.K, view.camera, view.config, view.name

    def fail(reason: str, matches: int = 0, inliers: int = 0, afd: float = math.nan, rms: float = math.nan):
        return _refused(reason, view, matcher=matcher, matches=matches, inliers=inliers, afd=afd, rms=rms)

    if len(p_ref) < min_inliers:
        return fail(f"only {len(p_ref)} feature matches with the reference image", len(p_ref))
    X, has = lift_reference_pixels(
        p_ref,
        ref_points=view.ref_points,
        T_ref_camref=view.T_ref_camref,
        camera=camera,
        radius_px=config.depth_search_px,
    )
    p_ref, p_cur = p_ref[has], p_cur[has]
    if len(p_ref) < min_inliers:
        return fail(f"only {len(p_ref)} of {len(has)} matches on the reference cloud", len(p_ref))
    n = len(p_ref)
    found, fit = pnp_fit(
        X, p_ref, p_cur, K, ransac_px=config.ransac_px, min_inliers=min_inliers, common_px=config.common_error_px
    )
    if fit is None:
        return fail(f"PnP found {found} inliers of {n}", n, found)
    inl, rms, afd, M_cam, sigma_mm = fit.inliers, fit.rms_px, fit.afd_px, fit.M_cam, fit.offset_sigma_mm
    mm, deg = pose_distance(np.eye(4), M_cam)
    if len(inl) / n < config.min_inlier_ratio:
        return fail(
            f"{len(inl)} PnP inliers of {n} matches (below {config.min_inlier_ratio:.0%})", n, len(inl), afd, rms
        )
    if rms > config.max_rms_px:
        return fail(f"PnP reprojection RMS {rms:.2f} px", n, len(inl), afd, rms)
    if mm > 1000 * config.max_motion_m or deg > config.max_motion_deg:
        refused = _refuse_large_motion(fit, mm, deg, n=n, view=view, matcher=matcher)
        if refused is not None:
            return refused
    return ImageRefinement(
        ok=True,
        reason="ok",
        M_cam=M_cam,
        measured_afd_px=afd,
        matches=n,
        inliers=len(inl),
        rms_px=rms,
        reference_image=name,
        matcher=matcher,
        offset_sigma_mm=sigma_mm,
    )


def _refused(
    reason: str, view: _ReferenceView, *, matcher: str, matches: int, inliers: int, afd: float, rms: float
) -> ImageRefinement:
    """A refused measurement of one reference image: no motion, the evidence counted for the log (px)."""
    return ImageRefinement(
        ok=False,
        reason=reason,
        M_cam=None,
        measured_afd_px=afd,
        matches=matches,
        inliers=inliers,
        rms_px=rms,
        reference_image=view.name,
        matcher=matcher,
    )


def _refuse_large_motion(
    fit: PnpFit, mm: float, deg: float, *, n: int, view: _ReferenceView, matcher: str
) -> ImageRefinement | None:
    """The verdict on a correction beyond ``max_motion_*``: None when the evidence is strong enough to act on it.

    Ordinary evidence refuses it (``unverified``, with one ordinary step toward it, up to
    ``strong_max_motion_*``); beyond ``strong_max_motion_*`` it is refused whatever the evidence (``oversize``
    when the evidence is strong).
    """
    config = view.config
    inl, rms, afd, M_cam, sigma_mm = fit.inliers, fit.rms_px, fit.afd_px, fit.M_cam, fit.offset_sigma_mm
    strong = len(inl) >= config.strong_min_inliers and len(inl) / n >= config.strong_min_inlier_ratio
    if not strong:
        reason = (
            f"correction of {mm:.1f} mm / {deg:.2f} deg is too large to trust on {len(inl)} inliers "
            f"of {n} (needs {config.strong_min_inliers} and {config.strong_min_inlier_ratio:.0%})"
        )
        if mm > 1000 * config.strong_max_motion_m or deg > config.strong_max_motion_deg:
            return _refused(reason, view, matcher=matcher, matches=n, inliers=len(inl), afd=afd, rms=rms)
        step, _ = clamp_motion(M_cam, max_step_m=config.max_motion_m, max_step_rad=math.radians(config.max_motion_deg))
        return ImageRefinement(
            ok=False,
            reason=reason,
            M_cam=M_cam,
            measured_afd_px=afd,
            matches=n,
            inliers=len(inl),
            rms_px=rms,
            reference_image=view.name,
            matcher=matcher,
            offset_sigma_mm=sigma_mm,
            unverified=True,
            step_M_cam=step,
        )
    if mm > 1000 * config.strong_max_motion_m or deg > config.strong_max_motion_deg:
        return ImageRefinement(
            ok=False,
            reason=f"correction of {mm:.1f} mm / {deg:.2f} deg is too large to trust on image evidence alone",
            M_cam=M_cam,
            measured_afd_px=afd,
            matches=n,
            inliers=len(inl),
            rms_px=rms,
            reference_image=view.name,
            matcher=matcher,
            offset_sigma_mm=sigma_mm,
            oversize=True,
        )
    return None
