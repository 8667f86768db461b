"""Use case: the feature displacement field and average feature displacement of two images (``fgcd afd``).

The authors' protocol (SIFT, ratio test, RANSAC homography inliers, mean
displacement in px), its lighting-robust grid variant, or point pairs picked by
hand; optionally the FDF quiver figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fgcd_cli.errors import UserInputError

__all__ = ["AfdMeasurement", "AfdRequest", "measure_afd", "write_fdf_figure"]


@dataclass(frozen=True, kw_only=True)
class AfdRequest:
    """Two images to compare and how (``fgcd afd``); ``grid`` and ``pairs`` exclude each other (UserInputError).

    Attributes
    ----------
    ref, cur : Path
        Reference and current image (same size).
    grid : bool
        The lighting-robust grid variant (phase correlation of gradient patches).
    pairs : Path or None
        CSV of point pairs ``x_ref,y_ref,x_cur,y_cur`` picked by hand.
    ratio : float
        SIFT ratio test.
    ransac_px : float
        RANSAC homography inlier threshold (px).
    """

    ref: Path
    cur: Path
    grid: bool = False
    pairs: Path | None = None
    ratio: float = 0.75
    ransac_px: float = 3.0

    def __post_init__(self) -> None:
        if self.grid and self.pairs is not None:
            raise UserInputError("give either --grid or --pairs, not both")


@dataclass(frozen=True, kw_only=True)
class AfdMeasurement:
    """Outcome of :func:`measure_afd`.

    Attributes
    ----------
    result : fgcd_cli.metrics.afd.FdfResult
        The field, its AFD and settings.
    record : dict
        ``fgcd afd --json``'s object (the result, the two image paths).
    ref_image : ndarray
        The reference image (the figure's background).
    """

    result: Any
    record: dict
    ref_image: np.ndarray


def measure_afd(request: AfdRequest) -> AfdMeasurement:
    """Read the two images and measure their feature displacement field."""
    from fgcd_cli.changes.io import read_image
    from fgcd_cli.metrics.afd import FdfConfig, compute_fdf, read_pairs_csv

    r = request
    ref_image, cur_image = read_image(r.ref), read_image(r.cur)
    if r.pairs is not None:
        result = compute_fdf(ref_image, cur_image, config=FdfConfig(method="pairs"), pairs=read_pairs_csv(r.pairs))
    else:
        result = compute_fdf(
            ref_image,
            cur_image,
            config=FdfConfig(method="grid" if r.grid else "sift", ratio=r.ratio, ransac_px=r.ransac_px),
        )
    record = result.as_dict()
    record["reference"], record["current"] = str(r.ref), str(r.cur)
    return AfdMeasurement(result=result, record=record, ref_image=ref_image)


def write_fdf_figure(measurement: AfdMeasurement, output: Path) -> None:
    """Write the FDF quiver figure (PNG) of ``measurement`` to ``output``, atomically."""
    from fgcd_cli.campaign.atomic import atomic_write_bytes
    from fgcd_cli.report.figures import fdf_quiver_png

    result = measurement.result
    atomic_write_bytes(
        output,
        fdf_quiver_png(
            measurement.ref_image,
            result.points_ref,
            result.points_cur,
            afd_px=result.afd_px,
            inliers=result.inliers,
            method=result.method,
        ),
    )
