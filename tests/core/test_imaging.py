"""fgcd_core.imaging: grey images by declared dtype and channel rule, 8-bit levels, CLAHE, SIFT and matching.

Known colours give their Rec. 601 luma (or their mean), 8-bit levels follow the stated rounding rule, SIFT
finds the shift of a shifted texture; undeclared dtypes and shapes are refused.
"""

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


def test_uint16_is_scaled_by_its_dtype():
    img = INPUTS["u16_gray"]
    _same(to_gray_f32(img), img.astype(np.float32) / 65535.0)
    assert float(to_gray_f32(INPUTS["u16_rgb"]).max()) <= 1.0


def _one_pixel(*rgb, dtype=np.uint8) -> np.ndarray:
    return np.array([[rgb]], dtype=dtype)


@pytest.mark.parametrize(
    "rgb, luma_u8", [((255, 0, 0), 76), ((0, 255, 0), 150), ((0, 0, 255), 29), ((255, 255, 255), 255), ((0, 0, 0), 0)]
)
def test_a_known_colour_gives_its_rec601_luma(rgb, luma_u8):
    """Y = 0.299 R + 0.587 G + 0.114 B, rounded to the integer type first (OpenCV), then scaled to [0, 1]."""
    img = _one_pixel(*rgb)
    assert to_gray_u8(img)[0, 0] == luma_u8
    assert to_gray_f32(img)[0, 0] == np.float32(luma_u8) / np.float32(255)
    # the camera sources' rule: no intermediate rounding
    exact = (0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]) / 255
    assert to_gray_f32(img, channels=GrayChannels.LUMA_601_F32)[0, 0] == pytest.approx(exact, abs=1e-6)
    assert to_gray_f32(img, channels=GrayChannels.MEAN)[0, 0] == pytest.approx(sum(rgb) / 3 / 255, abs=1e-6)
    # the alpha channel is ignored
    assert to_gray_u8(_one_pixel(*rgb, 7))[0, 0] == luma_u8
    assert (
        to_gray_f32(_one_pixel(*rgb, 7), channels=GrayChannels.MEAN)[0, 0]
        == to_gray_f32(img, channels=GrayChannels.MEAN)[0, 0]
    )


def test_other_dtypes_take_their_range_from_the_dtype():
    red16 = _one_pixel(65535, 0, 0, dtype=np.uint16)
    assert abs(float(to_gray_f32(red16)[0, 0]) * 65535 - 0.299 * 65535) <= 1.5  # luma within a 16-bit level
    colour = _one_pixel(0.2, 0.4, 0.6, dtype=np.float32)  # floats are taken as [0, 1]
    assert to_gray_f32(colour)[0, 0] == pytest.approx(0.299 * 0.2 + 0.587 * 0.4 + 0.114 * 0.6, abs=1e-6)
    assert to_gray_f32(colour, channels=GrayChannels.MEAN)[0, 0] == pytest.approx(0.4, abs=1e-7)
    assert to_gray_f32(colour.astype(np.float64)).dtype == np.float32


def test_eight_bit_levels_follow_the_rounding_rule():
    grey = np.array([[0.0, 1.0, -0.1, 1.2, 100.4 / 255, 100.6 / 255, 0.25, 0.75]], np.float32)
    half_up = [0, 255, 0, 255, 100, 101, 64, 191]  # floor(x * 255 + 0.5), clipped
    assert to_gray_u8(grey).tolist() == [half_up]
    assert to_gray_u8(grey, rounding=U8Rounding.HALF_UP_F64).tolist() == [half_up]
    assert to_gray_u8(grey, rounding=U8Rounding.TRUNCATE_F32).tolist() == [[0, 255, 0, 255, 100, 100, 63, 191]]
    u8 = np.arange(256, dtype=np.uint8).reshape(16, 16)
    assert np.array_equal(to_gray_u8(u8), u8)  # uint8 grey passes through unchanged
    assert np.array_equal(to_gray_f32(u8), u8.astype(np.float32) / 255.0)


@pytest.mark.parametrize("dtype", [np.uint8, np.float32, np.float64])
@pytest.mark.parametrize("colour", [False, True])
def test_every_frame_dtype_gives_grey_of_the_declared_type(dtype, colour):
    rng = np.random.default_rng(1)
    shape = (37, 53, 3) if colour else (37, 53)
    img = rng.integers(0, 256, shape).astype(np.uint8) if dtype == np.uint8 else rng.random(shape).astype(dtype)
    u8, f32 = to_gray_u8(img), to_gray_f32(img)
    assert u8.dtype == np.uint8 and f32.dtype == np.float32
    assert u8.shape == f32.shape == (37, 53)
    assert 0.0 <= float(f32.min()) and float(f32.max()) <= 1.0


def _shifted(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    return cv2.warpAffine(image, np.float32([[1, 0, dx], [0, 1, dy]]), image.shape[::-1])


def test_sift_matches_find_the_shift_of_a_shifted_texture_and_nothing_on_a_blank_image():
    ref = to_gray_u8(INPUTS["f32_gray"])
    cur = _shifted(ref, 4.0, -3.0)
    points_ref, points_cur = match_sift(ref, cur, ratio=0.75, max_features=4000)
    assert len(points_ref) > 20 and points_ref.dtype == np.float64
    np.testing.assert_allclose(np.median(points_cur - points_ref, axis=0), [4.0, -3.0], atol=0.1)
    blank_ref, blank_cur = match_sift(np.zeros_like(ref), cur)
    assert blank_ref.shape == blank_cur.shape == (0, 2)


def test_the_same_pair_matched_again_reuses_the_matches_and_a_changed_pixel_does_not(monkeypatch):
    """``fgcd diff`` matches its first pair for the registration and again for the FDF: one SIFT run.

    The memo is keyed by the pixels and the options, so a one-level change of one pixel, or another
    ratio, runs SIFT again; callers get their own copies (a caller's edit cannot reach the next).
    """
    import fgcd_core.imaging as imaging

    ref = to_gray_u8(INPUTS["f32_gray"])
    cur = _shifted(ref, 2.0, 1.0)
    calls = []
    real = imaging.sift_features
    monkeypatch.setattr(imaging, "sift_features", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(imaging, "_MATCH_MEMO", type(imaging._MATCH_MEMO)())
    first = match_sift(ref, cur)
    assert len(calls) == 2
    first[0][:] = -1.0  # the caller's copy
    again = match_sift(ref.copy(), cur.copy())
    assert len(calls) == 2
    np.testing.assert_allclose(np.median(again[1] - again[0], axis=0), [2.0, 1.0], atol=0.1)
    touched = cur.copy()
    touched[0, 0] ^= 1
    match_sift(ref, touched)
    match_sift(ref, cur, ratio=0.6)
    assert len(calls) == 6


def test_one_to_one_matching_uses_each_descriptor_once():
    """The hand-eye refinement's features: CLAHE'd SIFT, FLANN ratio test, every ``b`` descriptor matched once."""
    grey = to_gray_u8(INPUTS["f32_gray"], rounding=U8Rounding.TRUNCATE_F32)
    (xy_a, d_a), (xy_b, d_b) = [
        sift_features(clahe(im, clip_limit=3.0, tiles=8), n_features=1500) for im in (grey, _shifted(grey, 4.0, -3.0))
    ]
    assert d_a.dtype == np.float32 and d_a.shape == (len(xy_a), 128)
    cv2.setRNGSeed(11)  # FLANN's randomised kd-trees draw from OpenCV's global RNG
    idx = match_descriptors(d_a, d_b, ratio=0.8, matcher=DescriptorMatcher.FLANN, one_to_one=True)
    assert len(idx) > 20
    assert len(np.unique(idx[:, 1])) == len(idx)
    np.testing.assert_allclose(np.median(xy_b[idx[:, 1]] - xy_a[idx[:, 0]], axis=0), [4.0, -3.0], atol=0.1)


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
