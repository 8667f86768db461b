"""What a campaign diff knows of the reference's 3D: its depth (from the metric cloud) for the warp and
the areas (the report's sentences on it: :mod:`fgcd_cli.report.pose_check`)."""

from __future__ import annotations

import numpy as np

from fgcd_cli.campaign import schema
from fgcd_cli.changes.geometry.depth import ReferenceGeometry, geometry_from_cloud, smooth_known
from fgcd_cli.changes.regions import pixel_area_from_depth

__all__ = ["campaign_pixel_area", "reference_geometry"]

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
        area = pixel_area_from_depth(smooth_known(geometry.interpolated_depth, AREA_DEPTH_SMOOTH_PX), geometry.K)
        if np.isfinite(area).any():
            return area, "from the reference metric cloud"
    return None, "none (areas in px only)"
