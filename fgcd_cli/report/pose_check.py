"""The sentences on where a campaign visit's camera stood: the warp a diff used, the residual pose it
measured against the reference depth, and whether the relocation's own stated residual covers it."""

from __future__ import annotations

__all__ = ["MEASURED_POSE_ERROR_MM", "geometry_text", "relocation_check_text"]


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


# The measured pose's largest error against the simulator's truth on the bench visits (docs/change-detection.md,
# "Geometry of a campaign diff"): the reference cloud's own error, which any measurement against it shares.
# A relocation's stated residual is contradicted only beyond its 2 sigma plus this.
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
