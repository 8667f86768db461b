"""What a campaign diff knows of the reference's 3D: its depth (from the metric cloud) for the warp and
the areas, and how the report states the residual pose the diff measured against it."""

from __future__ import annotations

import numpy as np

from fgcd_cli.campaign import schema
from fgcd_cli.changes.geometry.depth import ReferenceGeometry, geometry_from_cloud, smooth_known
from fgcd_cli.changes.regions import pixel_area_from_depth

__all__ = ["campaign_pixel_area", "geometry_text", "reference_geometry"]

# Semi-dense clouds are noisy: the areas come from their depth smoothed over this many pixels.
AREA_DEPTH_SMOOTH_PX = 3.0


def reference_geometry(reference, shape: tuple[int, int]) -> ReferenceGeometry | None:
    """The reference's depth and camera at the image size ``shape`` (None without a stored cloud)."""
    from fgcd_core.camera import PinholeCamera

    meta = reference.metadata
    if not (
        reference.has(schema.array_relpath(schema.ARRAY_CLOUD_POINTS))
        and reference.has(schema.array_relpath(schema.ARRAY_T_REF_CAMREF))
        and meta.get("intrinsics")
    ):
        return None
    camera = PinholeCamera.from_dict(meta["intrinsics"])
    K = camera.K.copy()
    if (camera.width, camera.height) != (shape[1], shape[0]):
        K[0] *= shape[1] / camera.width
        K[1] *= shape[0] / camera.height
    return geometry_from_cloud(
        reference.array(schema.ARRAY_CLOUD_POINTS), reference.array(schema.ARRAY_T_REF_CAMREF), K, shape
    )


def campaign_pixel_area(
    geometry: ReferenceGeometry | None, shape: tuple[int, int], mm_per_px: float | None
) -> tuple[np.ndarray | None, str]:
    """mm² per reference pixel (the given scale, else the reference's metric cloud, else None) and how it was got."""
    if mm_per_px is not None:
        return np.full(shape, mm_per_px**2), f"{mm_per_px} mm per px (given)"
    if geometry is not None:
        area = pixel_area_from_depth(smooth_known(geometry.depth, AREA_DEPTH_SMOOTH_PX), geometry.K)
        if np.isfinite(area).any():
            return area, "from the reference metric cloud"
    return None, "none (areas in px only)"


def geometry_text(settings: dict) -> str:
    """One line for the report: the warp a campaign diff used and the residual pose it measured."""
    geo = settings.get("geometry")
    if not geo:
        return "homography and flow (no reference depth used)"
    if "residual_pose_mm" not in geo:
        return f"homography and flow: {geo.get('reason', 'the residual pose was not measured')}"
    return (
        f"by the reference depth; visit measured {geo['residual_pose_mm']:.2f} mm, "
        f"{geo['residual_pose_deg']:.3f}° from the reference ({geo['pnp_inliers']} of {geo['pnp_matches']} matches, "
        f"{geo['pnp_rms_px']:.2f} px); {100 * geo['depth_edge_fraction']:.1f} % of the image at depth edges not compared"
    )


# The measured pose's error against the simulator's truth on fgcd bench paper's stored visits: 0.12-0.68 mm
# over 14 visits (docs/lab/2026-12-06-campaign-geometry-and-small-changes.md): the reference cloud's own
# error, which a measurement against it shares. A relocation's stated residual is contradicted only
# beyond its 2 sigma plus this.
MEASURED_POSE_ERROR_MM = 0.7


def relocation_check_text(stated: dict | None, settings: dict) -> str:
    """Whether the relocation's own stated residual covers the pose the diff measured ("" when either
    is missing): ``measured 0.64 mm: within the relocation's stated 0.74 ± 0.45 mm``."""
    geo = settings.get("geometry") or {}
    if not isinstance(stated, dict) or "residual_pose_mm" not in geo:
        return ""
    try:
        offset, sigma = float(stated["offset_mm"]), float(stated["sigma_mm"])
    except (KeyError, TypeError, ValueError):
        return ""
    measured = float(geo["residual_pose_mm"])
    claim = f"the relocation's stated {offset:.2f} ± {sigma:.2f} mm"
    if abs(measured - offset) <= 2.0 * sigma + MEASURED_POSE_ERROR_MM:
        return f"measured {measured:.2f} mm: within {claim}"
    return (
        f"measured {measured:.2f} mm: beyond {claim} (2σ + {MEASURED_POSE_ERROR_MM} mm): "
        "its own estimate of where it stopped was wrong"
    )
