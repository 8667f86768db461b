"""Camera sources: the frame type, intrinsics, a device camera and image-folder replay.

Every camera of fgcd (a USB/industrial device through OpenCV, a folder of images
replayed in order, the simulator's camera) offers the same small interface,
:class:`CameraSource`: ``grab()`` returns a :class:`Frame`, ``intrinsics_nominal``
the intrinsics the camera advertises (which calibration refines), ``close()``.

Drivers never import ``fgcd_cli``; everything here is plain numpy data.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "Frame",
    "CameraIntrinsics",
    "CameraSource",
    "CameraError",
    "ImageFolderCamera",
    "OpenCVCamera",
    "to_gray_float",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


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
    """

    image: np.ndarray
    timestamp_s: float
    depth: np.ndarray | None = None
    rgb: np.ndarray | None = None


@dataclass(frozen=True, kw_only=True)
class CameraIntrinsics:
    """Pinhole intrinsics with OpenCV distortion ``(k1, k2, p1, p2, k3)``.

    Pixel centres sit at integer coordinates (OpenCV convention).
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
            raise ValueError("focal lengths and image size must be positive")
        d = tuple(float(x) for x in self.dist)
        if len(d) != 5:
            raise ValueError("dist must hold 5 coefficients (k1, k2, p1, p2, k3)")
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> np.ndarray:
        """Distortion coefficients as a float64 array of 5."""
        return np.asarray(self.dist, dtype=float)

    @property
    def has_distortion(self) -> bool:
        return any(abs(x) > 0 for x in self.dist)

    def scaled(self, factor: float) -> "CameraIntrinsics":
        """Intrinsics of the image resized by ``factor`` (pixel-centre convention)."""
        return CameraIntrinsics(
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            width=max(1, int(round(self.width * factor))),
            height=max(1, int(round(self.height * factor))),
            dist=self.dist,
        )

    def to_dict(self) -> dict:
        return {
            "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
            "width": self.width, "height": self.height, "dist": list(self.dist),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "CameraIntrinsics":
        return cls(
            fx=float(d["fx"]), fy=float(d["fy"]), cx=float(d["cx"]), cy=float(d["cy"]),
            width=int(d["width"]), height=int(d["height"]),
            dist=tuple(d.get("dist", (0.0,) * 5)),
        )


@runtime_checkable
class CameraSource(Protocol):
    """What every camera offers."""

    @property
    def intrinsics_nominal(self) -> CameraIntrinsics:
        """Intrinsics the camera advertises (datasheet or last calibration)."""

    def grab(self) -> Frame:
        """Take one frame now."""

    def close(self) -> None:
        """Release the device."""


def to_gray_float(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 in [0, 1] from a gray or colour uint8/uint16/float image."""
    img = np.asarray(image)
    if img.dtype == np.uint8:
        scale = 1.0 / 255.0
    elif img.dtype == np.uint16:
        scale = 1.0 / 65535.0
    else:
        scale = 1.0
    img = img.astype(np.float32) * np.float32(scale)
    if img.ndim == 3:
        img = img[:, :, :3] @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


class ImageFolderCamera:
    """Replays the images of a folder in sorted file-name order.

    Parameters
    ----------
    path : str or Path
        Folder holding png/jpg/tif images.
    intrinsics : CameraIntrinsics, optional
        What to advertise; by default a pinhole guess (focal = image width,
        centred principal point) from the first image's size.
    loop : bool
        Start again after the last image instead of raising.
    fps : float
        Timestamps advance by ``1/fps`` per frame.
    """

    def __init__(self, path, *, intrinsics: CameraIntrinsics | None = None, loop: bool = False, fps: float = 10.0):
        import cv2

        self.path = Path(path)
        if not self.path.is_dir():
            raise CameraError(f"image folder not found: {self.path}")
        self.files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise CameraError(f"no images (png/jpg/tif/bmp) in {self.path}")
        self.loop = loop
        self.fps = float(fps)
        self._index = 0
        first = cv2.imread(str(self.files[0]), cv2.IMREAD_UNCHANGED)
        if first is None:
            raise CameraError(f"cannot read image {self.files[0]}")
        h, w = first.shape[:2]
        self._intrinsics = intrinsics or CameraIntrinsics(
            fx=float(w), fy=float(w), cx=(w - 1) / 2.0, cy=(h - 1) / 2.0, width=w, height=h
        )

    @property
    def intrinsics_nominal(self) -> CameraIntrinsics:
        return self._intrinsics

    def __len__(self) -> int:
        return len(self.files)

    def grab(self) -> Frame:
        import cv2

        if self._index >= len(self.files):
            if not self.loop:
                raise CameraError(f"no more images in {self.path} ({len(self.files)} replayed)")
            self._index = 0
        path = self.files[self._index]
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise CameraError(f"cannot read image {path}")
        rgb = None
        if raw.ndim == 3:
            raw = cv2.cvtColor(raw[:, :, :3], cv2.COLOR_BGR2RGB)
            rgb = raw
        frame = Frame(to_gray_float(raw), self._index / self.fps, None, rgb)
        self._index += 1
        return frame

    def close(self) -> None:
        self._index = len(self.files)


class OpenCVCamera:
    """A camera device through ``cv2.VideoCapture``.

    Parameters
    ----------
    index : int or str
        Device index or a stream/file URL.
    width, height : int, optional
        Requested resolution.
    intrinsics : CameraIntrinsics, optional
        What to advertise; by default a pinhole guess from the frame size.
    """

    def __init__(self, index: int | str = 0, *, width: int | None = None, height: int | None = None,
                 intrinsics: CameraIntrinsics | None = None):
        import cv2

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
        return Frame(to_gray_float(rgb if rgb is not None else img), time.monotonic() - self._t0, None, rgb)

    def close(self) -> None:
        self._cap.release()
