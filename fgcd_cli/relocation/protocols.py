"""What relocation needs of the things it is given: the camera model and the image refiner."""

from __future__ import annotations

from typing import Protocol

import numpy as np

__all__ = ["CameraModel", "ImageRefiner"]


class CameraModel(Protocol):
    """Undistorted pinhole intrinsics (``fgcd_core.camera.PinholeCamera`` fits).

    ``fx fy cx cy`` in pixels, ``width height`` in pixels; ``project`` maps (N, 3)
    camera-frame points (metres) to (N, 2) pixels and an (N,) mask of points in
    front of the camera and inside the image.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...  # noqa: D102


class ImageRefiner(Protocol):
    """The camera motion to the reference pose measured from the reference images
    (:func:`fgcd_cli.relocation.image.refine.refine_from_reference_image` fits)."""

    def __call__(
        self,
        *,
        reference_images: dict[str, np.ndarray],
        current_image: np.ndarray,
        camera: CameraModel,
        ref_points: np.ndarray,
        T_ref_camref: np.ndarray,
    ): ...  # noqa: D102
