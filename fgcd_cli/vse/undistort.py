"""Undistort frames before the VSE sees them, as DSO does.

The engines assume an ideal pinhole; a real lens (and the simulator's camera)
has radial distortion of a few pixels at the border, which ruins monocular
accuracy (DSO's own warning: above ~1.5 px). Frames are remapped once with
OpenCV to an ideal pinhole with the same focal length and principal point.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_core.camera import PinholeCamera

__all__ = ["Undistorter", "UndistortedFrame", "UndistortedSource"]


class Undistorter:
    """Remaps images of a distorted camera to the ideal pinhole :attr:`ideal`."""

    def __init__(self, camera: PinholeCamera) -> None:
        self.camera = camera
        self.ideal = PinholeCamera(
            fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, width=camera.width, height=camera.height
        )
        self._map1, self._map2 = cv2.initUndistortRectifyMap(
            camera.K, np.array(camera.dist), None, self.ideal.K, (camera.width, camera.height), cv2.CV_32FC1
        )

    def image(self, image: np.ndarray) -> np.ndarray:
        """Bilinear remap of an image (grey or colour, any dtype OpenCV takes)."""
        return cv2.remap(np.asarray(image), self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """Nearest-neighbour remap of a z-depth image (no mixing across edges)."""
        return cv2.remap(
            np.asarray(depth, dtype=np.float32),
            self._map1,
            self._map2,
            cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0.0,
        )


@dataclass
class UndistortedFrame:
    """A frame remapped to the ideal pinhole."""

    image: np.ndarray
    timestamp_s: float
    depth: np.ndarray | None = None
    rgb: np.ndarray | None = None
    exposure: float | None = None


class UndistortedSource:
    """Wraps a camera source so every grabbed frame is undistorted."""

    def __init__(self, source, undistorter: Undistorter) -> None:
        self.source = source
        self.undistorter = undistorter
        lock = getattr(source, "exposure_locked", None)
        if lock is not None:
            # the optional capability of fgcd_drivers.cameras: offered exactly when the wrapped camera offers it
            self.exposure_locked = lock

    def grab(self) -> UndistortedFrame:
        return self._undistorted(self.source.grab())

    def grab_still(self) -> UndistortedFrame:
        """A still of the wrapped camera (``fgcd_drivers.cameras.CameraSource.grab_still``), undistorted."""
        return self._undistorted(self.source.grab_still())

    def _undistorted(self, f) -> UndistortedFrame:
        u = self.undistorter
        depth = getattr(f, "depth", None)
        rgb = getattr(f, "rgb", None)
        return UndistortedFrame(
            image=u.image(f.image),
            timestamp_s=f.timestamp_s,
            depth=None if depth is None else u.depth(depth),
            rgb=None if rgb is None else u.image(rgb),
            exposure=getattr(f, "exposure", None),
        )

    def synthetic_overhead_s(self, thread: int | None = None) -> float:
        """The wrapped source's frame-synthesis time (a simulator's rendering; 0 for real cameras);
        ``thread``: that thread's only (``SimCamera.synthetic_overhead_s``)."""
        inner = getattr(self.source, "synthetic_overhead_s", None)
        if inner is None:
            return 0.0
        return float(inner() if thread is None else inner(thread))

    def close(self) -> None:
        close = getattr(self.source, "close", None)
        if close:
            close()
