"""Input images for change detection: validation and conversion to float32 in [0, 1]."""

from __future__ import annotations

import numpy as np

from fgcd_cli.changes.config import MIN_REGION_CONTRAST
from fgcd_cli.errors import UserInputError
from fgcd_core.imaging import GrayChannels, to_gray_f32


def to_float_image(image: np.ndarray, *, name: str = "image") -> np.ndarray:
    """Convert an image to float32 in [0, 1], keeping its channels.

    Parameters
    ----------
    image : ndarray, HxW or HxWxC, uint8, uint16 or float
        Integer images are scaled by their dtype's maximum (so 16-bit input keeps
        its full dynamic range); float images must already lie in [0, 1].
    name : str
        Used in error messages.

    Returns
    -------
    ndarray, float32, same shape, values in [0, 1].
    """
    array = np.asarray(image)
    if array.ndim not in (2, 3) or array.shape[0] < 2 or array.shape[1] < 2:
        raise UserInputError(f"{name}: expected an HxW or HxWxC image, got shape {array.shape}")
    if array.ndim == 3 and array.shape[2] not in (1, 3, 4):
        raise UserInputError(f"{name}: expected 1, 3 or 4 channels, got {array.shape[2]}")
    if array.ndim == 3 and array.shape[2] == 4:
        array = array[:, :, :3]
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if np.issubdtype(array.dtype, np.integer):
        return (array.astype(np.float32) / float(np.iinfo(array.dtype).max)).astype(np.float32)
    if np.issubdtype(array.dtype, np.floating):
        finite = array[np.isfinite(array)]
        if finite.size and (finite.min() < -1e-3 or finite.max() > 1.0 + 1e-3):
            raise UserInputError(
                f"{name}: float images must lie in [0, 1] (got {finite.min():.3g}..{finite.max():.3g})"
            )
        return np.clip(np.nan_to_num(array, nan=0.0), 0.0, 1.0).astype(np.float32)
    raise UserInputError(f"{name}: unsupported pixel type {array.dtype}")


def to_gray(image: np.ndarray) -> np.ndarray:
    """The detector's grey level (HxW float32, a new array) of an image from :func:`to_float_image`.

    The rule is the unweighted mean of R, G and B (no channel order is assumed; it
    only feeds registration, the dense flow and the structure cues), computed by
    :func:`fgcd_core.imaging.to_gray_f32` with ``GrayChannels.MEAN``
    (docs/change-detection.md, "Change detection pipeline").
    """
    gray = to_gray_f32(image, channels=GrayChannels.MEAN)
    return gray.copy() if np.shares_memory(gray, image) else gray


def check_stack_sizes(ref_images: list[np.ndarray], cur_images: list[np.ndarray]) -> None:
    """Check that the stacks are non-empty, of equal length and of one image size (cheap: shapes only).

    Callers run it before announcing any work (``docs/change-detection.md``, "Commands"); raises
    :class:`UserInputError` naming the first image that does not fit.
    """
    if len(ref_images) == 0 or len(cur_images) == 0:
        raise UserInputError("need at least one reference and one current image")
    if len(ref_images) != len(cur_images):
        raise UserInputError(
            f"{len(ref_images)} reference image(s) but {len(cur_images)} current image(s): "
            "give one current image per reference lighting, in the same order"
        )
    shapes = [np.shape(im) for im in [*ref_images, *cur_images]]
    if len(shapes[0]) < 2:
        return  # not an image at all: to_float_image names it
    for i, shape in enumerate(shapes):
        if len(shape) >= 2 and shape[:2] != shapes[0][:2]:
            which = f"reference image {i + 1}" if i < len(ref_images) else f"current image {i - len(ref_images) + 1}"
            raise UserInputError(
                f"{which} is {shape[1]}x{shape[0]} px but reference image 1 is {shapes[0][1]}x{shapes[0][0]} px: "
                "all images must have the same size"
            )


def validate_stacks(
    ref_images: list[np.ndarray], cur_images: list[np.ndarray]
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Check and convert the reference and current image stacks (one image per lighting).

    Returns the two lists as float32 images in [0, 1]. Raises :class:`UserInputError`
    when the stacks are empty, of different lengths, or of different image sizes.
    """
    check_stack_sizes(ref_images, cur_images)
    refs = [to_float_image(im, name=f"reference image {i + 1}") for i, im in enumerate(ref_images)]
    curs = [to_float_image(im, name=f"current image {i + 1}") for i, im in enumerate(cur_images)]
    for im in refs + curs:
        if im.ndim != refs[0].ndim:
            raise UserInputError("mixing colour and grey images: give all images in colour or all in grey")
    return refs, curs


def check_side_inputs(
    shape: tuple[int, int],
    lightings: int,
    *,
    roi: np.ndarray | None,
    pixel_area_mm2: np.ndarray | None,
    registration_lighting: int,
) -> np.ndarray | None:
    """Check the maps and the lighting index that come with an HxW stack; returns the region of interest as bool.

    Raises :class:`UserInputError` when a map is not HxW or the lighting index is out of range.
    """
    if roi is not None:
        roi = np.asarray(roi).astype(bool)
        if roi.shape != shape:
            raise UserInputError(
                f"the region of interest (--roi) is {roi.shape[1]}x{roi.shape[0]} px, "
                f"images are {shape[1]}x{shape[0]} px"
            )
    if pixel_area_mm2 is not None and np.asarray(pixel_area_mm2).shape != shape:
        raise UserInputError("pixel area map must have the reference image's size")
    if not 0 <= registration_lighting < lightings:
        raise UserInputError(f"registration lighting {registration_lighting} out of range 0..{lightings - 1}")
    return roi


#: A channel at or above this fraction of full scale is clipped: the top code of an 8-bit image and
#: the code below it (JPEG and demosaicing leave clipped areas a code under the top); on deeper images
#: the same top 0.6 % of full scale (a 10- to 14-bit sensor's top code scaled to 16 bits included).
CLIP_LEVEL = 253.5 / 255.0


#: An 8-bit camera's dark noise, in codes: on the real FGCD statues' dark backgrounds (grey 12-14) the
#: difference of neighbouring pixels over sqrt 2 has a standard deviation of 1.5-1.9 codes (texture
#: included); the simulated field camera's black void, 2.4 codes at grey 6.
DARK_NOISE_CODES = 2.0

#: A pixel whose brightest channel is at or below this fraction of full scale is at the sensor's floor:
#: its dark noise alone is the contrast floor (:data:`~fgcd_cli.changes.config.MIN_REGION_CONTRAST`, a
#: change 20 % of the surface's brightness), so a difference there measures the noise (gamma-stretched
#: in the dark), not the surface. 10 codes of 8 bits (3.9 %).
FLOOR_LEVEL = DARK_NOISE_CODES / MIN_REGION_CONTRAST / 255.0


def clipped_pixels(image: np.ndarray) -> np.ndarray:
    """Pixels clipped at either end of the sensor's range: at its top code in any colour channel (their
    radiance lies somewhere above what the camera recorded) or at its floor in every channel (too dark to
    measure, :data:`FLOOR_LEVEL`). No difference there measures the surface
    (:mod:`fgcd_cli.changes.clip_check`).

    Parameters
    ----------
    image : (H, W) or (H, W, 3) float array in [0, 1].

    Returns
    -------
    (H, W) bool array.
    """
    top = image.max(axis=-1) if image.ndim == 3 else image
    return (top >= CLIP_LEVEL) | (top <= FLOOR_LEVEL)


def image_health(image: np.ndarray) -> str | None:
    """Why an image cannot be compared (too dark, saturated, textureless), or None if usable.

    Parameters
    ----------
    image : ndarray, HxW float32 in [0, 1]
    """
    mean = float(image.mean())
    if mean < 0.02:
        return f"image is black (mean level {mean * 100:.1f} %)"
    if mean > 0.98:
        return f"image is saturated (mean level {mean * 100:.1f} %)"
    # Texture: robust spread of the gradient magnitude. Fewer than 0.5 % of pixels
    # with a gradient above 2 grey levels per pixel means nothing to register on.
    gy, gx = np.gradient(image)
    strong = np.hypot(gx, gy) > 2.0 / 255.0
    if strong.mean() < 0.005:
        return "image has no texture to register on"
    return None
