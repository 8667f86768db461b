"""When relocation may stop, and what it states at the end (docs/relocation.md, "Stop rules").

A stage stops when the paper's rule (``g <= eta``) or the image-space rule
(estimated AFD below a pixel bound) holds *and* its estimate of the remaining
camera offset is within :func:`tolerance_mm`. After a converged 3D loop, the
image estimate must also agree with a 3D estimate of the same view within
their combined uncertainty (:func:`estimates_agree`). The run ends with a
:class:`Residual`: the remaining offset with its uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgcd_cli.relocation.enums import Agreement, EstimateSource
from fgcd_cli.relocation.protocols import CameraModel
from fgcd_core.se3 import invert_pose, transform_points

__all__ = [
    "Residual",
    "estimated_afd_px",
    "estimates_agree",
    "frame_afd_bound_px",
    "offset_vector_mm",
    "reference_depth_m",
    "tolerance_mm",
]


@dataclass(frozen=True, kw_only=True)
class Residual:
    """The remaining camera offset at the end of a run, as the tool's own estimate says.

    Attributes
    ----------
    offset_mm : float
        Distance between the current and the reference camera centres, mm.
    sigma_mm : float
        Its 1-sigma uncertainty (RMS radius of the position's uncertainty), mm.
    tolerance_mm : float
        The stop tolerance the run used, mm.
    source : EstimateSource
        "image" (PnP on the reference images) or "3d" (cloud alignment).
    agreement : str
        How the other estimator compared (:class:`~fgcd_cli.relocation.enums.Agreement`,
        possibly with a note: ``"not checked: ..."``).
    """

    offset_mm: float
    sigma_mm: float
    tolerance_mm: float
    source: EstimateSource | str
    agreement: str = Agreement.NOT_CHECKED

    def text(self) -> str:
        """One phrase for people: ``residual 0.99 ± 0.23 mm (image estimate; tolerance 1.36 mm)``."""
        return (
            f"residual {self.offset_mm:.2f} ± {self.sigma_mm:.2f} mm ({self.source} estimate; "
            f"tolerance {self.tolerance_mm:.2f} mm; 3D/image: {self.agreement})"
        )

    def to_dict(self) -> dict:
        """Plain data for JSON output."""
        return dict(self.__dict__)


def reference_depth_m(ref_points: np.ndarray, T_ref_camref: np.ndarray) -> float:
    """Median depth of the reference cloud in front of the reference camera, metres.

    Parameters
    ----------
    ref_points : (N, 3) ndarray
        Reference cloud, metres, ``ref`` frame.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.

    Returns
    -------
    float
        NaN when no point is in front of the camera.
    """
    P = np.asarray(ref_points, dtype=float).reshape(-1, 3)
    T = np.asarray(T_ref_camref, dtype=float)
    z = (P - T[:3, 3]) @ T[:3, 2]
    z = z[z > 1e-6]
    return float(np.median(z)) if len(z) else math.nan


def tolerance_mm(
    ref_points: np.ndarray, T_ref_camref: np.ndarray, camera: CameraModel | None, *, stop_afd_px: float
) -> float:
    """Stop tolerance on the remaining camera offset, mm (docs/relocation.md, "Stop rules").

    Model: a sideways camera shift ``d`` at distance ``Z`` moves the object's image by
    ``f d / Z`` pixels, so the image-space stop rule (``stop_afd_px``) corresponds to
    ``d = stop_afd_px * Z / f``: the pixel footprint on the object times the pixel
    tolerance. A shift that a small turn hides (a nearly flat object) escapes the AFD,
    not this rule.

    Parameters
    ----------
    ref_points : (N, 3) ndarray
        Reference cloud, metres.
    T_ref_camref : (4, 4) ndarray
        Reference camera pose.
    camera : PinholeCamera or None
        Intrinsics (``fx``, ``fy`` in pixels).
    stop_afd_px : float
        The image-space stop rule, pixels.

    Returns
    -------
    float
        Millimetres; ``inf`` without a camera or a cloud in front of it (no model: the
        paper's ``g <= eta`` rule stands alone).
    """
    if camera is None:
        return math.inf
    z = reference_depth_m(ref_points, T_ref_camref)
    f = 0.5 * (float(camera.fx) + float(camera.fy))
    if not math.isfinite(z) or f <= 0:
        return math.inf
    return 1000.0 * stop_afd_px * z / f


def estimates_agree(
    offset_a_mm: np.ndarray, sigma_a_mm: float, offset_b_mm: np.ndarray, sigma_b_mm: float, *, k: float
) -> tuple[bool, float, float]:
    """Whether two estimates of the camera position agree within their uncertainties.

    Parameters
    ----------
    offset_a_mm, offset_b_mm : (3,) ndarray
        Camera centre minus the reference camera centre, ``ref`` frame, mm.
    sigma_a_mm, sigma_b_mm : float
        Their RMS-radius uncertainties, mm; a non-finite one (an estimator that gave
        none) counts as 0, so the bound rests on the other.
    k : float
        Allowed multiple of the combined RMS radius ``sqrt(sa^2 + sb^2)``. For an
        isotropic error, ``|e| > 2 x RMS radius`` has probability ~0.7 % (chi-square, 3 dof).

    Returns
    -------
    agree : bool
    distance_mm : float
        ``|a - b|``.
    bound_mm : float
        ``k sqrt(sa^2 + sb^2)``.
    """
    d = float(np.linalg.norm(np.asarray(offset_a_mm, dtype=float) - np.asarray(offset_b_mm, dtype=float)))
    sa, sb = (float(x) if math.isfinite(float(x)) else 0.0 for x in (sigma_a_mm, sigma_b_mm))
    bound = k * math.hypot(sa, sb)
    return bool(d <= bound), d, bound


def frame_afd_bound_px(*, stop_afd_px: float, rms_px: float, inliers: int, k: float) -> float:
    """Largest AFD the frames themselves may show when the camera is within the image-space stop rule, px.

    Model: a match's displacement between the reference and the current image is the true
    displacement ``d_i`` plus matching noise ``n_i`` with ``E|n|^2 = rms^2`` (the PnP inliers'
    reprojection RMS). Then ``mean|d_i + n_i| <= sqrt(mean|d_i + n_i|^2) ~ sqrt(AFD^2 + rms^2)``
    for displacements of similar size, and the mean over ``n`` matches scatters by about
    ``rms / sqrt(n)``; ``k`` of those are allowed.

    Parameters
    ----------
    stop_afd_px : float
        The image-space stop rule, px.
    rms_px : float
        RMS reprojection error of the PnP inliers, px (NaN or inf: no bound can be stated).
    inliers : int
        Number of matches the measured AFD averages.
    k : float
        Allowed multiple of the mean's scatter.

    Returns
    -------
    float
        Pixels; NaN when ``rms_px`` or ``inliers`` give no model.
    """
    if not math.isfinite(rms_px) or inliers < 1:
        return math.nan
    return math.hypot(stop_afd_px, rms_px) + k * rms_px / math.sqrt(inliers)


def offset_vector_mm(T_ref_cam: np.ndarray, T_ref_camref: np.ndarray) -> np.ndarray:
    """Current minus reference camera centre, ``ref`` frame, mm, shape (3,)."""
    return 1000.0 * (np.asarray(T_ref_cam, dtype=float)[:3, 3] - np.asarray(T_ref_camref, dtype=float)[:3, 3])


def estimated_afd_px(
    ref_points: np.ndarray,
    T_ref_camref: np.ndarray,
    T_ref_cam: np.ndarray,
    camera: CameraModel | None,
    *,
    max_points: int = 3000,
) -> float:
    """Mean image displacement (px) between the reference camera and the estimated current one.

    The reference points seen by the reference camera are projected into both
    cameras; the mean distance between the two projections is the AFD the
    remaining offset would produce, as far as the estimate knows.

    Parameters
    ----------
    ref_points : (N, 3) ndarray
        Reference cloud, metres, ``ref`` frame (at most ``max_points`` of them, evenly picked, are used).
    T_ref_camref, T_ref_cam : (4, 4) ndarray
        Reference and estimated current camera poses.
    camera : PinholeCamera or None
        Intrinsics with ``project``.

    Returns
    -------
    float
        Pixels; ``inf`` without a camera, a cloud, or a point both cameras see.
    """
    P = np.asarray(ref_points, dtype=float)
    if len(P) > max_points:
        P = P[np.linspace(0, len(P) - 1, max_points).astype(int)]
    if camera is None or len(P) == 0:
        return float("inf")
    uv_ref, ok_ref = camera.project(transform_points(invert_pose(T_ref_camref), P))
    uv_cur, ok_cur = camera.project(transform_points(invert_pose(T_ref_cam), P))
    ok = ok_ref & np.isfinite(uv_cur).all(axis=1)
    if not np.any(ok):
        return float("inf")
    return float(np.mean(np.linalg.norm(uv_cur[ok] - uv_ref[ok], axis=1)))
