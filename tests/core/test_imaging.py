"""fgcd_core.imaging reproduces every grey converter, CLAHE and SIFT matcher it replaces, bit for bit.

Each old copy (tests/core/legacy_gray.py) is compared with the canonical call
that replaces it, on uint8, uint16 and float inputs; where the declared-dtype
rule deliberately differs from an old copy's guess, the test says so.
"""

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

from fgcd_core.imaging import (
    DescriptorMatcher,
    GrayChannels,
    U8Rounding,
    clahe,
    match_descriptors,
    match_sift,
    sift_features,
    to_gray_f32,
    to_gray_u8,
)

_spec = importlib.util.spec_from_file_location("legacy_gray", Path(__file__).with_name("legacy_gray.py"))
legacy = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(legacy)


def _texture(h=180, w=240, seed=0) -> np.ndarray:
    """Float32 RGB in [0, 1] with structure at several scales (SIFT finds keypoints on it)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w, 3), np.float32)
    for sigma in (1.0, 3.0, 8.0):
        img += cv2.GaussianBlur(rng.normal(0, 1, (h, w, 3)).astype(np.float32), (0, 0), sigma) * sigma
    img -= img.min()
    return (img / img.max()).astype(np.float32)


RGB_F32 = _texture()
INPUTS = {
    "u8_rgb": (RGB_F32 * 255 + 0.5).astype(np.uint8),
    "u16_rgb": (RGB_F32 * 65535 + 0.5).astype(np.uint16),
    "f32_rgb": RGB_F32,
    "f64_rgb": RGB_F32.astype(np.float64) * 0.999 + 0.0005,
    "u8_rgba": np.dstack([(RGB_F32 * 255 + 0.5).astype(np.uint8), np.full(RGB_F32.shape[:2], 7, np.uint8)]),
}
INPUTS.update({k.replace("rgb", "gray"): v[..., 1].copy() for k, v in list(INPUTS.items()) if k.endswith("rgb")})


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape
    assert np.array_equal(a, b)


@pytest.mark.parametrize("name", sorted(INPUTS))
def test_camera_sources_pipeline(name):
    """fgcd_drivers.cameras.to_gray_float == to_gray_f32(channels=LUMA_601_F32) on every dtype."""
    _same(to_gray_f32(INPUTS[name], channels=GrayChannels.LUMA_601_F32),
          legacy.drivers_cameras_to_gray_float(INPUTS[name]))


@pytest.mark.parametrize("name", sorted(k for k in INPUTS if not k.startswith("u16")))
def test_vse_converters(name):
    """vse.features.to_gray_f32 / to_gray_u8 == the defaults (uint16 differs: it was not scaled)."""
    _same(to_gray_f32(INPUTS[name]), legacy.vse_features_to_gray_f32(INPUTS[name]))
    _same(to_gray_u8(INPUTS[name]), legacy.vse_features_to_gray_u8(INPUTS[name]))


def test_uint16_is_scaled_by_its_dtype():
    img = INPUTS["u16_gray"]
    _same(to_gray_f32(img), img.astype(np.float32) / 65535.0)
    assert float(to_gray_f32(INPUTS["u16_rgb"]).max()) <= 1.0


@pytest.mark.parametrize("name", ["u8_rgb", "u8_rgba", "u8_gray", "f32_gray", "f64_gray"])
def test_board_converter(name):
    """calibration.board._to_gray_u8 == to_gray_u8(rounding=HALF_UP_F64) (float RGB: luma, was the mean)."""
    _same(to_gray_u8(INPUTS[name], rounding=U8Rounding.HALF_UP_F64), legacy.calibration_board_to_gray_u8(INPUTS[name]))


@pytest.mark.parametrize("name", ["u8_rgb", "u8_gray", "f32_rgb", "f32_gray", "f64_gray"])
def test_handeye_converter(name):
    """handeye_ba.gray_u8 == to_gray_u8(rounding=TRUNCATE_F32) on [0, 1] floats (it guessed [0, 255] otherwise)."""
    _same(to_gray_u8(INPUTS[name], rounding=U8Rounding.TRUNCATE_F32), legacy.handeye_ba_gray_u8(INPUTS[name]))


@pytest.mark.parametrize("name", ["f32_rgb", "f32_gray"])
def test_change_detection_mean(name):
    """changes.images.to_gray and changes.tiled._gray == to_gray_f32(channels=MEAN) on their float32 inputs."""
    _same(to_gray_f32(INPUTS[name], channels=GrayChannels.MEAN), legacy.changes_images_to_gray(INPUTS[name]))
    _same(to_gray_f32(INPUTS[name], channels=GrayChannels.MEAN), legacy.changes_tiled_gray(INPUTS[name]))


@pytest.mark.parametrize("name", ["u8_rgb", "u8_gray", "f32_rgb", "f32_gray", "f64_gray"])
def test_photometric_converter(name):
    """alignment.photometric._as_float_gray == to_gray_f32() (it could not take float64 colour)."""
    _same(to_gray_f32(INPUTS[name]), legacy.alignment_photometric_as_float_gray(INPUTS[name]))


@pytest.mark.parametrize("name", ["f32_gray", "f64_gray"])
def test_local_contrast(name):
    """relocation.image_refine.local_contrast == to_gray_f32(clahe(to_gray_u8(g), clip_limit=3, tiles=8))."""
    g = INPUTS[name]
    _same(to_gray_f32(clahe(to_gray_u8(g), clip_limit=3.0, tiles=8)), legacy.relocation_local_contrast(g))


def test_registration_uint8_and_match_sift():
    """changes.registration.match_sift(ref, cur) == match_sift(to_gray_u8(ref), to_gray_u8(cur))."""
    ref = INPUTS["f32_gray"]
    H = np.array([[1.0, 0.02, 3.0], [-0.01, 1.0, -2.0], [0.0, 0.0, 1.0]], np.float32)
    cur = cv2.warpPerspective(ref, H, ref.shape[::-1])
    _same(to_gray_u8(ref), legacy.registration_to_uint8(ref))
    old = legacy.registration_match_sift(ref, cur, ratio=0.75, max_features=4000)
    new = match_sift(to_gray_u8(ref), to_gray_u8(cur), ratio=0.75, max_features=4000)
    assert len(old[0]) > 20
    _same(new[0], old[0])
    _same(new[1], old[1])
    blank = np.zeros_like(ref)
    for a, b in zip(match_sift(to_gray_u8(blank), to_gray_u8(cur)), legacy.registration_match_sift(blank, cur)):
        _same(a, b)


def test_handeye_features_and_matching():
    """handeye_ba.stop_features and its ratio-test, one-to-one FLANN matching."""
    images = [INPUTS["f32_gray"], cv2.warpAffine(INPUTS["f32_gray"], np.float32([[1, 0, 4], [0, 1, -3]]), (240, 180))]
    old = legacy.handeye_ba_stop_features(images)
    new = [sift_features(clahe(to_gray_u8(im, rounding=U8Rounding.TRUNCATE_F32), clip_limit=3.0, tiles=8),
                         n_features=1500) for im in images]
    for (xo, do), (xn, dn) in zip(old, new):
        _same(xn, xo)
        _same(dn, do)
    # FLANN's randomised kd-trees draw from OpenCV's global RNG: both runs start from the same seed
    cv2.setRNGSeed(11)
    idx = match_descriptors(new[0][1], new[1][1], ratio=0.8, matcher=DescriptorMatcher.FLANN, one_to_one=True)
    cv2.setRNGSeed(11)
    assert len(idx) > 20
    _same(idx, legacy.handeye_ba_ratio_one_to_one(old[0][1], old[1][1], ratio=0.8))


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.bool_, np.float16])
def test_undeclared_dtypes_raise(dtype):
    with pytest.raises(TypeError):
        to_gray_f32(np.zeros((4, 4), dtype))
    with pytest.raises(TypeError):
        to_gray_u8(np.zeros((4, 4, 3), dtype))


def test_bad_shapes_and_clahe_input():
    with pytest.raises(ValueError):
        to_gray_f32(np.zeros((4, 4, 2), np.uint8))
    with pytest.raises(TypeError):
        clahe(np.zeros((4, 4), np.float32), clip_limit=3.0, tiles=8)


def test_enums_keep_their_string_values():
    assert GrayChannels.LUMA_601 == "luma601" and U8Rounding.HALF_UP_F32 == "half_up_f32"
    assert DescriptorMatcher.FLANN == "flann"
