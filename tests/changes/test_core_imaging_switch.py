"""The grey conversion, 8-bit rounding and SIFT matching of the change detector, now through fgcd_core.imaging,
give what the detector's own copies gave (tests/core/legacy_gray.py keeps them, verbatim, as the reference)."""

import importlib.util
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.changes.images import to_gray
from fgcd_cli.changes.registration import match_sift, to_uint8
from fgcd_cli.changes.tiled_input import as_float, gray_mean

from .conftest import textured_scene, translate

# the former copies, kept verbatim once, in tests/core/legacy_gray.py
_spec = importlib.util.spec_from_file_location("legacy_gray", Path(__file__).resolve().parents[1] / "core" / "legacy_gray.py")
legacy = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(legacy)


def _same(a, b):
    assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)


def _images():
    rng = np.random.default_rng(5)
    rgb32 = rng.random((64, 80, 3), dtype=np.float32)
    return {"rgb32": rgb32, "grey32": rgb32[:, :, 1].copy(), "rgb64": rgb32.astype(np.float64) ** 1.3,
            "grey64": rgb32[:, :, 0].astype(np.float64) ** 0.7, "rgba32": rng.random((64, 80, 4), dtype=np.float32),
            "edges32": np.array([[0.0, 1.0, 0.5 / 255.0, 1.5 / 255.0], [-0.1, 1.2, 0.25, 0.75]], np.float32)}


def test_grey_conversions_are_the_old_ones():
    images = _images()
    for name in ("rgb32", "grey32", "grey64"):  # what to_float_image hands the detector, and grey float64
        _same(to_gray(images[name]), legacy.changes_images_to_gray(images[name]))
    # float64 colour is now averaged after the cast to float32 (the core rule): within a few float32 ulps of [0, 1]
    np.testing.assert_allclose(to_gray(images["rgb64"]), legacy.changes_images_to_gray(images["rgb64"]),
                               rtol=0, atol=3 * 2.0**-23)
    # RGBA: the alpha channel no longer enters the mean (to_float_image drops it before the detector anyway)
    rgba = images["rgba32"]
    _same(to_gray(rgba), legacy.changes_images_to_gray(np.ascontiguousarray(rgba[:, :, :3])))
    grey = images["grey32"]
    assert not np.shares_memory(to_gray(grey), grey)
    u8 = (np.random.default_rng(1).random((40, 30, 3)) * 255).astype(np.uint8)
    for small in (u8, u8[:, :, 0], np.random.default_rng(2).random((40, 30, 3)).astype(np.float32)):
        _same(gray_mean(as_float(small)), legacy.changes_tiled_gray(as_float(small)))


def test_eight_bit_rounding_is_the_old_one():
    for image in _images().values():
        if image.ndim == 2:
            _same(to_uint8(image), legacy.registration_to_uint8(image))


def test_sift_matches_are_the_old_ones():
    ref = textured_scene(256)
    cur = translate(ref, 3.2, -1.7)
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)  # SIFT's keypoint order follows OpenCV's thread scheduling: compare single-threaded
    try:
        old, new = legacy.registration_match_sift(ref, cur), match_sift(ref, cur)
        assert len(old[0]) > 50
        _same(new[0], old[0])
        _same(new[1], old[1])
        for a, b in zip(match_sift(np.zeros_like(ref), cur), legacy.registration_match_sift(np.zeros_like(ref), cur)):
            _same(a, b)
    finally:
        cv2.setNumThreads(before)
