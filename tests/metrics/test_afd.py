import numpy as np
import pytest
from changes.conftest import textured_scene, translate

from fgcd_cli.errors import AlgorithmError, UserInputError
from fgcd_cli.metrics.afd import FdfConfig, compute_fdf, read_pairs_csv

SHIFT = (2.4, -1.3)
TRUE_AFD = float(np.hypot(*SHIFT))


@pytest.fixture(scope="module")
def pair():
    ref = textured_scene(256)
    gain = np.linspace(0.7, 1.2, 256, dtype=np.float32)[None, :]
    return ref, np.clip(translate(ref, *SHIFT) * gain, 0, 1)


def test_sift_afd_of_a_pure_translation(pair):
    result = compute_fdf(*pair, config=FdfConfig(method="sift"))
    # SIFT keypoints localize to ~0.1 px on a textured image; the mean over
    # hundreds of inliers is much tighter.
    assert result.afd_px == pytest.approx(TRUE_AFD, abs=0.1)
    assert result.inliers >= 50
    assert result.settings["ratio"] == 0.75 and result.settings["ransac_px"] == 3.0
    assert np.allclose(result.displacements.mean(axis=0), SHIFT, atol=0.1)


def test_grid_afd_under_gain_ramp(pair):
    result = compute_fdf(*pair, config=FdfConfig(method="grid", grid_cells=6, patch_px=64))
    # Per patch the phase-correlation shift scatters by ~0.4 px on this fine
    # texture; over >= 20 patches the mean vector is good to 3 * 0.4 / sqrt(20) ~ 0.25 px.
    assert result.inliers >= 20
    assert np.allclose(result.displacements.mean(axis=0), SHIFT, atol=0.25)
    assert result.afd_px == pytest.approx(TRUE_AFD, abs=0.3)


def test_user_pairs(tmp_path, pair):
    path = tmp_path / "pairs.csv"
    path.write_text("x_ref,y_ref,x_cur,y_cur\n10,10,13,14\n20,20,20,20\n")
    points = read_pairs_csv(path)
    result = compute_fdf(*pair, config=FdfConfig(method="pairs"), pairs=points)
    assert result.afd_px == pytest.approx(2.5)
    assert result.inliers == 2


def test_bad_pairs_file(tmp_path):
    path = tmp_path / "pairs.csv"
    path.write_text("1,2,3\n")
    with pytest.raises(UserInputError, match="expected 4 numbers"):
        read_pairs_csv(path)


def test_textureless_pair_is_an_algorithm_error():
    flat = np.full((128, 128), 0.5, np.float32)
    with pytest.raises(AlgorithmError, match="grid"):
        compute_fdf(flat, flat, config=FdfConfig(method="sift"))


def test_size_mismatch(pair):
    with pytest.raises(UserInputError, match="equal sizes"):
        compute_fdf(pair[0], pair[1][:100])


def _turned_and_shifted(deg: float, shift: tuple[float, float]):
    """A textured scene and the same turned by ``deg`` about its centre and shifted by ``shift`` (px):
    (reference, current, H) with H the reference-pixel -> current-pixel homography, (3, 3)."""
    import cv2

    ref = textured_scene(256)
    angle = np.radians(deg)
    c, s = np.cos(angle), np.sin(angle)
    centre = np.array([127.5, 127.5])
    R = np.array([[c, -s], [s, c]])
    H = np.eye(3)
    H[:2, :2] = R
    H[:2, 2] = centre + np.asarray(shift) - R @ centre
    cur = cv2.warpPerspective(ref, H, (256, 256), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return ref, cur, H


def _corner_error_px(result, H) -> float:
    """Mean distance of the image corners mapped by the cells' least-squares homography and by ``H``, px."""
    import cv2

    H_cells, _ = cv2.findHomography(result.points_ref, result.points_cur, 0)
    corners = np.array([[0, 0, 1], [255, 0, 1], [255, 255, 1], [0, 255, 1]], float).T
    mapped = lambda M: (M @ corners)[:2] / (M @ corners)[2]  # noqa: E731
    return float(np.linalg.norm(mapped(H_cells) - mapped(H), axis=0).mean())


def test_grid_afd_measures_a_motion_larger_than_its_patches_reach():
    # 16 px and 3 degrees across 32 px patches: from no motion, fewer than half the cells lock onto it
    # (the grid refuses); started from the whole image's ECC motion (metrics/afd.py: _grid_start) they agree
    ref, cur, H = _turned_and_shifted(3.0, (16.0, -6.4))
    cur = np.clip(cur * np.linspace(0.8, 1.1, 256, dtype=np.float32)[None, :], 0, 1)
    result = compute_fdf(ref, cur, config=FdfConfig(method="grid", grid_cells=6, patch_px=32))
    assert result.inliers >= 8
    # the cells' least-squares homography lands on the true one: each cell is within the 3 px RANSAC and
    # about 1 px RMS (phase correlation of 32 px gradient patches), ~25 cells, corners extrapolate ~3x
    assert _corner_error_px(result, H) < 1.0


def test_grid_reaches_a_start_beyond_ecc_from_the_whole_image_shift(monkeypatch):
    # 40 px and 2 degrees, the light inverted (an edge lit from the other side): ECC from no motion is
    # refused at this distance; the shift of the orientation fields across the whole image brings it in.
    import fgcd_cli.metrics.afd as afd

    ref, cur, H = _turned_and_shifted(2.0, (40.0, -12.0))
    cur = np.clip(1.0 - 0.8 * cur, 0, 1)
    config = FdfConfig(method="grid", grid_cells=6, patch_px=32)
    result = compute_fdf(ref, cur, config=config)
    assert result.inliers >= 8
    assert _corner_error_px(result, H) < 1.0
    # negative control: without the whole-image shift the start is no motion, and the grid refuses
    monkeypatch.setattr(afd, "_coarse_shift", lambda ref_gray, cur_gray: np.eye(3))
    with pytest.raises(AlgorithmError, match="grid"):
        compute_fdf(ref, cur, config=config)
