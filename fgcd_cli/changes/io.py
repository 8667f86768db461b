"""Reading image sets from files for change detection (the CLI's bare-image mode)."""

from __future__ import annotations

import glob
import re
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.errors import UserInputError


def _natural_key(path: str) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path)]


def expand_image_args(values: list[str], *, what: str) -> list[Path]:
    """Expand repeated/comma-separated paths and glob patterns into an ordered list of files."""
    paths: list[Path] = []
    for value in values:
        for item in (v.strip() for v in str(value).split(",")):
            if not item:
                continue
            if any(ch in item for ch in "*?["):
                matches = sorted(glob.glob(item), key=_natural_key)
                if not matches:
                    raise UserInputError(f"{what}: no file matches {item!r}")
                paths.extend(Path(m) for m in matches)
            else:
                paths.append(Path(item))
    if not paths:
        raise UserInputError(f"{what}: no image given")
    return paths


_SIGNATURES = (
    (b"\x89PNG\r\n\x1a\n", "PNG"),
    (b"\xff\xd8\xff", "JPEG"),
    (b"II*\x00", "TIFF"),
    (b"MM\x00*", "TIFF"),
    (b"BM", "BMP"),
    (b"\x00\x00\x00\x0cjP  ", "JPEG 2000"),
    (b"\x76\x2f\x31\x01", "OpenEXR"),
    (b"#?RADIANCE", "Radiance HDR"),
    (b"P5", "PGM"),
    (b"P6", "PPM"),
)
_JPEG_TAIL_BYTES = 4096  # the end-of-image marker is looked for this close to the end (trailing padding allowed)


def _image_format(head: bytes) -> str | None:
    """The image format a file's first bytes announce, or None."""
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WebP"
    return next((name for magic, name in _SIGNATURES if head.startswith(magic)), None)


def _truncated_jpeg(path: Path, size: int) -> bool:
    """A JPEG without its end-of-image marker (FF D9) near its end: cut short (OpenCV would fill the rest grey)."""
    with open(path, "rb") as f:
        f.seek(max(0, size - _JPEG_TAIL_BYTES))
        return b"\xff\xd9" not in f.read()


def read_image(path: Path) -> np.ndarray:
    """Read an image file as RGB (or grey), keeping 16-bit depth; one clear error if unreadable.

    The error says which: not found, an empty (0-byte) file, a file of a known
    format that is damaged or truncated (a JPEG cut short included, which OpenCV
    would otherwise decode with its missing rows grey), or a format OpenCV does not know.
    """
    path = Path(path)
    if not path.is_file():
        raise UserInputError(f"image not found: {path}")
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            fmt = _image_format(f.read(16))
        truncated = fmt == "JPEG" and _truncated_jpeg(path, size)
    except OSError as exc:
        raise UserInputError(f"cannot read image {path} ({exc.strerror or exc})") from None
    if size == 0:
        raise UserInputError(f"cannot read image {path}: empty file (0 bytes)")
    image = None if truncated else cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        if fmt is not None:
            raise UserInputError(f"cannot read image {path}: damaged or truncated {fmt} file ({size} bytes)")
        raise UserInputError(f"cannot read image {path} (not an image format OpenCV knows)")
    if image.ndim == 3 and image.shape[2] == 4:
        image = image[:, :, :3]
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    return image


def read_mask(path: Path) -> np.ndarray:
    """Read a mask image (non-zero = inside) as HxW bool."""
    image = read_image(path)
    if image.ndim == 3:
        image = image.max(axis=2)
    return image > 0
