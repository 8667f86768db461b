"""Pinhole camera with OpenCV's Brown–Conrady distortion ``(k1, k2, p1, p2, k3)``.

Camera frame as OpenCV: x right, y down, z forward; pixel centres at integer
coordinates. Distortion and its inverse go through OpenCV (``projectPoints``,
``undistortPointsIter``) rather than a hand-written solver.

The one intrinsics type of fgcd: ``fgcd_drivers.cameras.CameraIntrinsics`` (what a
camera advertises) and ``fgcd_core.camera.PinholeCamera`` (what the
algorithms project with) are both this class. Its JSON form (:meth:`to_dict`)
is the one written to ``rig/intrinsics.json``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["PinholeCamera", "CameraIntrinsics", "pinhole_pixels"]

#: Depth (metres) below which :func:`pinhole_pixels` divides by this value instead
MIN_DEPTH_M = 1e-9


def pinhole_pixels(K: np.ndarray, points_cam: np.ndarray) -> np.ndarray:
    """The one ideal (undistorted) pinhole projection ``u = fx x / z + cx``, ``v = fy y / z + cy``.

    Parameters
    ----------
    K : (3, 3) ndarray
        Intrinsics (no skew).
    points_cam : (N, 3) ndarray
        Camera-frame points, metres.

    Returns
    -------
    (N, 2) ndarray
        Pixels. A depth of magnitude below :data:`MIN_DEPTH_M` is taken as
        ``MIN_DEPTH_M`` (no division by zero); points behind the camera project
        through the centre, so callers judge them by their depth.
    """
    z = points_cam[:, 2]
    zs = np.where(np.abs(z) < MIN_DEPTH_M, MIN_DEPTH_M, z)
    return np.column_stack([K[0, 0] * points_cam[:, 0] / zs + K[0, 2], K[1, 1] * points_cam[:, 1] / zs + K[1, 2]])


@dataclass(frozen=True, kw_only=True)
class PinholeCamera:
    """Intrinsics of a pinhole camera.

    Attributes
    ----------
    fx, fy : float
        Focal lengths in pixels.
    cx, cy : float
        Principal point in pixels.
    width, height : int
        Image size in pixels.
    dist : tuple of 5 floats
        ``(k1, k2, p1, p2, k3)``; all zero for an ideal pinhole.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if not (self.fx > 0 and self.fy > 0 and self.width > 0 and self.height > 0):
            raise ValueError("camera focal lengths and image size must be positive")
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist))
        if len(self.dist) != 5:
            raise ValueError("dist must hold 5 coefficients (k1, k2, p1, p2, k3)")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # -- constructors / conversions
    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int, dist=None) -> PinholeCamera:
        """From a 3x3 matrix ``K``."""
        K = np.asarray(K, dtype=float)
        d = (
            (0.0,) * 5
            if dist is None
            else tuple(np.asarray(dist, dtype=float).ravel()[:5]) + (0.0,) * max(0, 5 - np.asarray(dist).size)
        )
        return cls(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], width=int(width), height=int(height), dist=d)

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> np.ndarray:
        """Distortion coefficients ``(k1, k2, p1, p2, k3)`` as a float64 array of 5."""
        return np.asarray(self.dist, dtype=float)

    @property
    def has_distortion(self) -> bool:
        """True if any distortion coefficient is non-zero."""
        return any(abs(d) > 0 for d in self.dist)

    def scaled(self, factor: float) -> PinholeCamera:
        """Intrinsics of the image resized by ``factor`` (pyramid levels use 0.5, 0.25...).

        Uses the pixel-centre convention: ``c' = (c + 0.5) * factor - 0.5``.
        """
        return PinholeCamera(
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            width=max(1, int(round(self.width * factor))),
            height=max(1, int(round(self.height * factor))),
            dist=self.dist,
        )

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
            "dist": list(self.dist),
        }

    @classmethod
    def from_dict(cls, data: dict) -> PinholeCamera:
        """Inverse of :meth:`to_dict`."""
        return cls(
            fx=float(data["fx"]),
            fy=float(data["fy"]),
            cx=float(data["cx"]),
            cy=float(data["cy"]),
            width=int(data["width"]),
            height=int(data["height"]),
            dist=tuple(data.get("dist", (0.0,) * 5)),
        )

    # -- projection
    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project camera-frame points to pixels.

        Parameters
        ----------
        points_cam : (N, 3) ndarray
            Points in the camera frame, metres.

        Returns
        -------
        uv : (N, 2) ndarray
            Pixel coordinates (NaN for points behind the camera).
        in_view : (N,) bool ndarray
            In front of the camera and inside the image.
        """
        P = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        z = P[:, 2]
        front = z > 1e-9
        uv = np.full((len(P), 2), np.nan)
        if self.has_distortion:
            if np.any(front):
                pts, _ = cv2.projectPoints(
                    P[front].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), self.K, np.array(self.dist)
                )
                uv[front] = pts.reshape(-1, 2)
        else:
            uv[front] = pinhole_pixels(self.K, P[front])
        in_view = (
            front
            & (uv[:, 0] >= -0.5)
            & (uv[:, 0] <= self.width - 0.5)
            & (uv[:, 1] >= -0.5)
            & (uv[:, 1] <= self.height - 0.5)
        )
        return uv, in_view

    def normalized_rays(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates ``(x, y, 1)`` of pixels, shape (N, 3)."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        if len(uv) == 0:
            return np.zeros((0, 3))
        if self.has_distortion:
            xy = cv2.undistortPointsIter(
                uv.reshape(-1, 1, 2),
                self.K,
                np.array(self.dist),
                None,
                None,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
            ).reshape(-1, 2)
        else:
            xy = np.column_stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy])
        return np.column_stack([xy, np.ones(len(xy))])

    def unproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points at z-depth ``depth`` (N,) for pixels ``uv`` (N, 2)."""
        rays = self.normalized_rays(uv)
        return rays * np.asarray(depth, dtype=float).reshape(-1, 1)

    def backproject_depth(self, depth: np.ndarray, *, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points of every valid pixel of a z-depth image.

        Parameters
        ----------
        depth : (H, W) ndarray
            z-depth in metres; 0, negative or non-finite means no measurement.
        stride : int
            Keep every ``stride``-th pixel in both directions.

        Returns
        -------
        points_cam : (N, 3) ndarray
            Points in metres.
        pixels : (N, 2) int ndarray
            ``(u, v)`` pixel of each point.
        """
        depth = np.asarray(depth, dtype=float)
        if depth.shape != (self.height, self.width):
            raise ValueError(f"depth is {depth.shape}, camera is {(self.height, self.width)}")
        v, u = np.mgrid[0 : self.height : stride, 0 : self.width : stride]
        d = depth[v, u]
        ok = np.isfinite(d) & (d > 0)
        uv = np.column_stack([u[ok], v[ok]]).astype(float)
        return self.unproject(uv, d[ok]), uv.astype(int)


#: The name the drivers' camera sources use for the same intrinsics.
CameraIntrinsics = PinholeCamera
