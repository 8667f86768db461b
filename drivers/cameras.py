"""Camera sources: the frame type, the intrinsics they advertise, and a device camera.

Every camera of fgcd (a USB/industrial device through OpenCV, the simulator's
camera) offers the same small interface,
:class:`CameraSource`: ``grab()`` returns a :class:`Frame` of the stream the
VSE tracks, ``grab_still()`` a still of the quality an observation stores (a
still camera's capture rather than its live view), ``intrinsics_nominal`` the
intrinsics the camera advertises (which calibration refines), ``close()``.

A camera that can hold its exposure also offers ``exposure_locked()``, a context
manager under which every frame keeps the exposure of its last still: a lamp's
own image is the difference of two stills at one exposure (``fgcd_core.flash``).
Without it the rig takes no lamp-only image.

Drivers never import ``fgcd_cli``; everything here is plain numpy data and the
shared bottom layer :mod:`fgcd_core` (intrinsics, grey conversion).
"""

from __future__ import annotations

import os
import stat
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from fgcd_core.camera import CameraIntrinsics
from fgcd_core.imaging import GrayChannels, to_gray_f32

__all__ = ["Frame", "CameraSource", "CameraError", "OpenCVCamera"]


class CameraError(RuntimeError):
    """A camera cannot be opened or stopped delivering frames (one line for a person)."""


@dataclass(kw_only=False)
class Frame:
    """One image from a camera.

    Attributes
    ----------
    image : ndarray
        Grayscale image, (H, W) float32 in [0, 1] or uint8.
    timestamp_s : float
        Capture time in seconds (simulated time on the simulator).
    depth : ndarray or None
        (H, W) float32 z-depth in metres, 0 where unknown (RGB-D cameras only).
    rgb : ndarray or None
        (H, W, 3) colour image, same dtype convention as ``image``.
    exposure : float or None
        The exposure (relative gain) the frame was taken at, None where the camera does not say.
    """

    image: np.ndarray
    timestamp_s: float
    depth: np.ndarray | None = None
    rgb: np.ndarray | None = None
    exposure: float | None = None


@runtime_checkable
class CameraSource(Protocol):
    """What every camera offers."""

    @property
    def intrinsics_nominal(self) -> CameraIntrinsics:
        """Intrinsics the camera advertises (datasheet or last calibration)."""

    def grab(self) -> Frame:
        """Take one frame of the stream now."""

    def grab_still(self) -> Frame:
        """Take one still now: what a reference or a visit stores (same size and intrinsics as ``grab``)."""

    def close(self) -> None:
        """Release the device."""


def _device_path(index: int | str) -> str | None:
    """The file of a camera: a Linux index's ``/dev/videoN``, an absolute path; None for URLs and pipelines."""
    if isinstance(index, int) or (isinstance(index, str) and index.isdigit()):
        return f"/dev/video{int(index)}" if sys.platform.startswith("linux") else None
    return index if isinstance(index, str) and index.startswith("/") else None


def _check_device(index: int | str) -> None:
    """Name a camera device that is absent or forbidden before OpenCV tries it (its own words go to a log)."""
    path = _device_path(index)
    if path is None:
        return
    if not os.path.exists(path):
        which = "" if path == index else f" (camera {index})"
        raise CameraError(f"no camera at {path}{which}: connect it, or choose another with --camera")
    if stat.S_ISCHR(os.stat(path).st_mode) and not os.access(path, os.R_OK | os.W_OK):
        raise CameraError(f"no permission to open camera {path} (add the user to the group owning it, usually 'video')")


class OpenCVCamera:
    """A camera device through ``cv2.VideoCapture``.

    Parameters
    ----------
    index : int or str
        Device index, device path or a stream/file URL. An index whose
        ``/dev/videoN`` or an absolute path that does not exist, or a device
        without permission, is refused (:class:`CameraError`) before OpenCV tries it.
    width, height : int, optional
        Requested resolution.
    intrinsics : CameraIntrinsics, optional
        What to advertise; by default a pinhole guess from the frame size.
    """

    def __init__(
        self,
        index: int | str = 0,
        *,
        width: int | None = None,
        height: int | None = None,
        intrinsics: CameraIntrinsics | None = None,
    ):
        import cv2

        _check_device(index)
        self._cap = cv2.VideoCapture(index)
        if not self._cap.isOpened():
            self._cap.release()
            raise CameraError(f"cannot open camera {index!r} (not connected, busy, or no permission)")
        if width:
            self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        if height:
            self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        ok, img = self._cap.read()
        if not ok or img is None:
            self._cap.release()
            raise CameraError(f"camera {index!r} opened but delivers no frames")
        h, w = img.shape[:2]
        self._intrinsics = intrinsics or CameraIntrinsics(
            fx=float(w), fy=float(w), cx=(w - 1) / 2.0, cy=(h - 1) / 2.0, width=w, height=h
        )
        self._t0 = time.monotonic()

    @property
    def intrinsics_nominal(self) -> CameraIntrinsics:
        return self._intrinsics

    def grab(self) -> Frame:
        import cv2

        ok, img = self._cap.read()
        if not ok or img is None:
            raise CameraError("camera stopped delivering frames")
        rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if img.ndim == 3 else None
        gray = to_gray_f32(rgb if rgb is not None else img, channels=GrayChannels.LUMA_601_F32)
        return Frame(gray, time.monotonic() - self._t0, None, rgb)

    def grab_still(self) -> Frame:
        """A device read through OpenCV has one stream: a still is its next frame."""
        return self.grab()

    @contextmanager
    def exposure_locked(self):
        """Hold the exposure the device uses now (manual mode), automatic again after.

        Backends name the modes differently (V4L2: 1 manual, 3 automatic; older
        OpenCV: 0.25 and 0.75); the first the device accepts is used. A device that
        accepts neither cannot lock: :class:`CameraError`, and no lamp-only image is taken.
        """
        import cv2

        previous = self._cap.get(cv2.CAP_PROP_AUTO_EXPOSURE)
        exposure = self._cap.get(cv2.CAP_PROP_EXPOSURE)
        if not any(self._cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, manual) for manual in (1, 0.25)):
            raise CameraError("this camera cannot lock its exposure (no manual exposure mode)")
        self._cap.set(cv2.CAP_PROP_EXPOSURE, exposure)
        try:
            yield
        finally:
            self._cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, previous)

    def close(self) -> None:
        self._cap.release()
