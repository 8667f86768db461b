import cv2
import numpy as np

from fgcd_cli.changes.registration import (
    ecc_gradient,
    match_sift,
    overlap_fraction,
    register_to_reference,
    to_uint8,
    warp_to_reference,
    without_ipp,
)

from .conftest import textured_scene, translate


def test_recovers_subpixel_shift_under_gain_ramp(scene_pair):
    reg = register_to_reference(scene_pair["ref"], scene_pair["cur"])
    assert reg.ok, reg.reason
    dx, dy = scene_pair["shift"]
    # A reference pixel x appears at x + d in the current image.
    mapped = reg.H_cur_ref @ np.array([128.0, 128.0, 1.0])
    mapped = mapped[:2] / mapped[2]
    # Notes: gradient ECC reaches 0.02-0.05 px on real pairs; 0.1 px leaves room for the disc change.
    assert abs(mapped[0] - 128.0 - dx) < 0.1
    assert abs(mapped[1] - 128.0 - dy) < 0.1


def test_warp_returns_reference_frame_and_valid_mask(scene_pair):
    reg = register_to_reference(scene_pair["ref"], scene_pair["cur"])
    warped, valid = warp_to_reference(scene_pair["cur"], reg.H_cur_ref, scene_pair["ref"].shape)
    assert warped.shape == scene_pair["ref"].shape
    # Shifted by ~2 px: a band of about 2-3 px on two sides is not seen.
    assert 0.95 < valid.mean() < 0.995


def test_overlap_fraction_of_half_shift():
    H = np.array([[1.0, 0, 100.0], [0, 1, 0], [0, 0, 1]])
    assert abs(overlap_fraction(H, (200, 200)) - 0.5) < 0.03


def test_ecc_that_wanders_off_a_good_sift_start_does_not_make_the_pair_incomparable(monkeypatch):
    """ECC ending below the correlation bar is judged against the SIFT homography by the same criterion."""
    import numpy as _np

    from changes.conftest import textured_scene, translate
    from fgcd_cli.changes import registration as reg

    ref = textured_scene(256)
    cur = translate(ref, 1.5, 0.8)
    wandered = _np.array([[1.0, 0.0, 40.0], [0.0, 1.0, -30.0], [0.0, 0.0, 1.0]])
    monkeypatch.setattr(reg, "ecc_gradient", lambda *a, **k: (wandered, 0.10))
    result = reg.register_to_reference(ref, cur)
    assert result.ok, result.reason
    # the SIFT homography is kept: the 1.5 / 0.8 px shift, not the wandered 40 / -30 px
    assert abs(result.H_cur_ref[0, 2] - 1.5) < 0.2 and abs(result.H_cur_ref[1, 2] - 0.8) < 0.2
    assert result.ecc_correlation > 0.3


def test_ecc_returns_the_same_homography_wherever_the_image_lies_in_memory():
    """The same pair registers the same way every time: with OpenCV's IPP kernels the ECC result
    depended on the buffer's alignment (two values for a float32 image at even and odd offsets)."""
    rng = np.random.default_rng(0)
    ref = cv2.GaussianBlur(rng.random((480, 640)).astype(np.float32), (0, 0), 2.0)
    H_true = np.array([[1.001, 0.002, 1.3], [-0.001, 0.999, -0.8], [1e-6, 0.0, 1.0]])
    cur = cv2.warpPerspective(ref, H_true, (640, 480), flags=cv2.INTER_LINEAR)
    results = set()
    for offset in range(4):
        buffer = np.empty(ref.size + 16, np.float32)
        ref_at_offset = buffer[offset : offset + ref.size].reshape(ref.shape)
        ref_at_offset[:] = ref
        results.add(ecc_gradient(ref_at_offset, cur, np.eye(3))[0].tobytes())
    assert len(results) == 1


def test_without_ipp_restores_the_callers_setting():
    before = cv2.ipp.useIPP()
    with without_ipp():
        assert not cv2.ipp.useIPP()
    assert cv2.ipp.useIPP() == before


def test_eight_bit_levels_round_half_up_in_the_images_precision():
    grey = np.array([[0.0, 1.0, -0.1, 1.2], [100.4 / 255, 100.6 / 255, 0.25, 0.75]])
    for image in (grey.astype(np.float32), grey):
        levels = to_uint8(image)
        assert levels.dtype == np.uint8 and levels.tolist() == [[0, 255, 0, 255], [100, 101, 64, 191]]


def test_sift_matches_follow_the_shift_and_a_blank_image_has_none():
    ref = textured_scene(256)
    cur = translate(ref, 3.2, -1.7)
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)  # SIFT's keypoint order follows OpenCV's thread scheduling: one thread, one order
    try:
        points_ref, points_cur = match_sift(ref, cur)
        assert len(points_ref) > 50 and points_ref.shape == points_cur.shape
        np.testing.assert_allclose(np.median(points_cur - points_ref, axis=0), [3.2, -1.7], atol=0.1)
        blank_ref, blank_cur = match_sift(np.zeros_like(ref), cur)
        assert blank_ref.shape == blank_cur.shape == (0, 2)
    finally:
        cv2.setNumThreads(before)
