"""Input of the tiled detector: 8-bit image files, stack checks without conversion, crops and downscales to float.

The stacks are kept as given (uint8 HxWx3: 14 x 24 MP is ~1 GB); a float32 copy
exists only for the crop being processed (``docs/change-detection.md``, large frames).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from fgcd_cli.errors import UserInputError
from fgcd_core.imaging import GrayChannels, to_gray_f32


def load_images(paths: Sequence[str | os.PathLike], *, workers: int = 2) -> list[np.ndarray]:
    """Read image files as 8-bit RGB arrays (HxWx3 uint8), the memory-light input of :func:`detect_changes_tiled`.

    16-bit files are reduced to 8 bits (the detector's cue resolution is far coarser
    than 1/255); a missing or unreadable file raises :class:`UserInputError`.
    """

    def read(path) -> np.ndarray:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise UserInputError(f"cannot read image {path}")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB, dst=image)

    if workers > 1 and len(paths) > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:  # PNG decoding releases the GIL
            return list(pool.map(read, paths))
    return [read(path) for path in paths]


# --------------------------------------------------------------------------- input


def check_stacks(ref_images, cur_images) -> tuple[tuple[int, int], int]:
    """Validate without converting (the stacks may be large); returns (H, W) and the channel count."""
    if len(ref_images) == 0 or len(cur_images) == 0:
        raise UserInputError("need at least one reference and one current image")
    if len(ref_images) != len(cur_images):
        raise UserInputError(
            f"{len(ref_images)} reference image(s) but {len(cur_images)} current image(s): "
            "give one current image per reference lighting, in the same order"
        )
    first = np.asarray(ref_images[0])
    shape, ndim = first.shape[:2], first.ndim
    for i, image in enumerate(list(ref_images) + list(cur_images)):
        which = f"reference image {i + 1}" if i < len(ref_images) else f"current image {i - len(ref_images) + 1}"
        image = np.asarray(image)
        if image.ndim not in (2, 3) or image.shape[0] < 2 or image.shape[1] < 2:
            raise UserInputError(f"{which}: expected an HxW or HxWx3 image, got shape {image.shape}")
        if image.ndim == 3 and image.shape[2] not in (1, 3, 4):
            raise UserInputError(f"{which}: expected 1, 3 or 4 channels, got {image.shape[2]}")
        if image.shape[:2] != shape:
            raise UserInputError(
                f"{which} is {image.shape[1]}x{image.shape[0]} px but reference image 1 is {shape[1]}x{shape[0]} px: "
                "all images must have the same size"
            )
        if image.ndim != ndim:
            raise UserInputError("mixing colour and grey images: give all images in colour or all in grey")
        if not (np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)):
            raise UserInputError(f"{which}: unsupported pixel type {image.dtype}")
    return shape, (1 if ndim == 2 else 3)


def crop_float(image: np.ndarray, y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    """float32 [0, 1] copy of a crop (grey or RGB; alpha dropped), as :func:`to_float_image` converts."""
    crop = np.asarray(image)[y0:y1, x0:x1]
    if crop.ndim == 3:
        crop = crop[:, :, 0] if crop.shape[2] == 1 else crop[:, :, :3]
    if np.issubdtype(crop.dtype, np.integer):
        out = crop.astype(np.float32)
        out /= np.float32(np.iinfo(crop.dtype).max)  # bit-identical to to_float_image
        return out
    return np.clip(np.nan_to_num(crop.astype(np.float32), nan=0.0), 0.0, 1.0)


def downscale(image: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """Area-averaged version of a whole image at ``size_wh``: 8-bit stays 8-bit, others become float32 [0, 1].

    8-bit images are averaged as they are (the result is rounded to 1/255, far below
    what registration and the photometric cues resolve); others through one float
    copy. :func:`as_float` gives the float32 [0, 1] image either way.
    """
    array = np.asarray(image)
    h, w = array.shape[:2]
    if array.dtype == np.uint8:
        return array if (w, h) == size_wh else cv2.resize(array, size_wh, interpolation=cv2.INTER_AREA)
    full = crop_float(array, 0, h, 0, w)
    return full if (w, h) == size_wh else cv2.resize(full, size_wh, interpolation=cv2.INTER_AREA)


def as_float(small: np.ndarray) -> np.ndarray:
    """float32 [0, 1] version of a :func:`downscale` result (as :func:`to_float_image` converts)."""
    return crop_float(small, 0, small.shape[0], 0, small.shape[1]) if small.dtype == np.uint8 else small


def gray_mean(image: np.ndarray) -> np.ndarray:
    """Channel mean of an :func:`as_float` image (float32 [0, 1], grey or RGB), as
    :func:`fgcd_cli.changes.images.to_gray` computes it (grey images are returned as they are)."""
    if image.ndim == 2:
        return image
    return to_gray_f32(image, channels=GrayChannels.MEAN)
