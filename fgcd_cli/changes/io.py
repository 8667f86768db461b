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


def read_image(path: Path) -> np.ndarray:
    """Read an image file as RGB (or grey), keeping 16-bit depth; one clear error if unreadable."""
    if not Path(path).is_file():
        raise UserInputError(f"image not found: {path}")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
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
