"""Tiled, bounded-memory detection (fgcd_cli.changes.tiled.pipeline) against the untiled detector."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from skimage import data

from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.tiled.geometry import tile_grid
from fgcd_cli.changes.tiled.inputs import load_images
from fgcd_cli.changes.tiled.pipeline import detect_changes_tiled
from fgcd_cli.errors import UserInputError
from fgcd_cli.metrics.change_scores import binary_scores

from .conftest import translate

H, W = 1000, 1200
TILE = 400  # 3 x 3 tiles: seams at x = 400, 800 and y = 333, 667
DISCS = ((300, 200, 14), (800, 500, 16), (1000, 820, 12))  # (x, y, r); the second sits on a tile corner
SHIFT = (1.3, -0.8)
FAST = dict(cues=False)


def _scene() -> np.ndarray:
    """A 1200 x 1000 photographic texture (scikit-image 'gravel', tiled and mirrored), float32 in [0, 1]."""
    gravel = data.gravel().astype(np.float32) / 255.0
    big = np.block([[gravel, gravel[:, ::-1], gravel], [gravel[::-1], gravel[::-1, ::-1], gravel[::-1]]])
    return np.ascontiguousarray(big[:H, :W])


def _pair(*, changed: bool = True, shift=SHIFT):
    ref = _scene()
    truth = np.zeros((H, W), bool)
    cur = ref.copy()
    if changed:
        for x, y, r in DISCS:
            cv2.circle(truth.view(np.uint8), (x, y), r, 1, -1)
        cur[truth] = 0.85
    cur = translate(cur, *shift) if shift != (0, 0) else cur
    gain = np.linspace(0.8, 1.2, W, dtype=np.float32)[None, :]
    cur = np.clip(cur * gain, 0, 1)
    # Two lightings, 8-bit as a camera gives them.
    to8 = lambda im: np.round(im * 255).astype(np.uint8)  # noqa: E731
    refs = [to8(ref), to8(np.clip(ref * 0.7, 0, 1))]
    curs = [to8(cur), to8(np.clip(cur * 0.7, 0, 1))]
    return refs, curs, truth


@pytest.fixture(scope="module")
def changed_pair():
    refs, curs, truth = _pair()
    calls = []
    plain = detect_changes(refs, curs, config=DetectionConfig.from_options(**FAST))
    tiled = detect_changes_tiled(
        refs, curs, progress=lambda *a: calls.append(a), config=DetectionConfig.from_options(tile_px=TILE, **FAST)
    )
    return {"refs": refs, "curs": curs, "truth": truth, "plain": plain, "tiled": tiled, "calls": calls}


def test_tiled_finds_the_same_changes_as_untiled(changed_pair):
    plain, tiled, truth = changed_pair["plain"], changed_pair["tiled"], changed_pair["truth"]
    assert tiled.comparable, tiled.reason
    assert tiled.settings["tiled"]["tiles"] == 9
    f1_plain = binary_scores(plain.mask, truth).f1
    f1_tiled = binary_scores(tiled.mask, truth).f1
    assert f1_plain > 0.7
    # The registration itself jitters by ~0.02 px from run to run (threaded SIFT/ECC),
    # which moves the score of this sharp texture by a few percent: not a tiling effect.
    assert abs(f1_tiled - f1_plain) < 0.03
    assert binary_scores(tiled.mask, plain.mask).f1 > 0.95
    # Every disc, including the one on a tile corner, is one region of the tiled result.
    for x, y, _ in DISCS:
        assert tiled.labels[y, x] > 0
    assert len(tiled.regions) == len(plain.regions)


def test_score_maps_agree_everywhere():
    # Without registration (no jitter between the two runs), tiling alone is compared.
    refs, curs, _ = _pair(shift=(0, 0))
    plain = detect_changes(refs, curs, config=DetectionConfig.from_options(register=False, **FAST))
    tiled = detect_changes_tiled(refs, curs, config=DetectionConfig.from_options(tile_px=TILE, register=False, **FAST))
    both = plain.valid & tiled.valid
    assert binary_scores(tiled.valid, plain.valid).iou > 0.999
    relative = np.abs(tiled.score - plain.score)[both] / np.maximum(plain.score[both], 1e-3)
    # Same cue, same global medians; differences are the float16 storage of the
    # per-lighting cue and the reduced-grid wide gain window anchored per tile.
    assert np.percentile(relative, 99) < 0.01
    # Largest departures: next to the changes, where the gain falls back to its wide
    # window, computed on a reduced grid anchored at each tile's origin.
    assert np.mean(relative > 0.02) < 0.005
    assert relative.max() < 0.25


def test_no_seams_on_an_unchanged_pair():
    refs, curs, _ = _pair(changed=False)
    result = detect_changes_tiled(refs, curs, config=DetectionConfig.from_options(tile_px=TILE, **FAST))
    assert result.comparable, result.reason
    score, valid = result.score, result.valid
    seam = np.zeros((H, W), bool)
    for tile in tile_grid((H, W), TILE, 0):
        y0, y1, x0, x1 = tile.core
        for x in (x0, x1):
            seam[:, max(0, x - 3) : x + 3] = True
        for y in (y0, y1):
            seam[max(0, y - 3) : y + 3, :] = True
    seam[:20], seam[-20:], seam[:, :20], seam[:, -20:] = False, False, False, False  # the frame border is not a seam
    at_seams, inside = score[seam & valid], score[~seam & valid]
    assert at_seams.size > 10000
    assert abs(np.median(at_seams) / np.median(inside) - 1.0) < 0.03
    assert abs(np.percentile(at_seams, 99) / np.percentile(inside, 99) - 1.0) < 0.1
    assert result.changed_fraction < 0.002


def test_progress_is_called_once_per_tile_in_order(changed_pair):
    calls = changed_pair["calls"]
    total = calls[0][1]
    assert all(c[1] == total for c in calls)
    assert [c[0] for c in calls] == list(range(1, total + 1))
    tiles = [c[2] for c in calls if "tile" in c[2]]
    passes = 1 + changed_pair["tiled"].settings["robust_gain_rounds"]
    assert len(tiles) == 9 * passes
    assert tiles[:9] == [f"gain pass: tile {i}/9" for i in range(1, 10)]
    assert calls[-1][2] == "decided"


def test_working_resolution_registration_is_scaled_to_full_resolution():
    refs, curs, truth = _pair()
    result = detect_changes_tiled(refs, curs, config=DetectionConfig.from_options(tile_px=600, work_px=600, **FAST))
    assert result.settings["work_scale"] == pytest.approx(2.0)
    # Content moved by SHIFT: reference pixel x is seen at x + SHIFT in the current image.
    H_full = result.registration.H_cur_ref
    mapped = H_full @ np.array([600.0, 500.0, 1.0])
    assert mapped[:2] / mapped[2] == pytest.approx([600 + SHIFT[0], 500 + SHIFT[1]], abs=0.15)
    assert binary_scores(result.mask, truth).f1 > 0.7


def test_bad_input_is_a_user_error(tmp_path):
    refs, curs, _ = _pair()
    with pytest.raises(UserInputError, match="same size"):
        detect_changes_tiled(refs, [curs[0][:500], curs[1][:500]])
    with pytest.raises(UserInputError, match="at least one"):
        detect_changes_tiled([], [])
    with pytest.raises(UserInputError, match="one current image per reference lighting"):
        detect_changes_tiled(refs, curs[:1])
    with pytest.raises(UserInputError, match="region of interest"):
        detect_changes_tiled(refs, curs, roi=np.ones((10, 10), bool))
    with pytest.raises(UserInputError, match="cannot read"):
        load_images([tmp_path / "missing.png"])


def test_load_images_reads_8_bit_rgb(tmp_path):
    image = np.zeros((20, 30, 3), np.uint8)
    image[..., 0] = 200  # red in RGB
    cv2.imwrite(str(tmp_path / "a.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    (loaded,) = load_images([tmp_path / "a.png"])
    assert loaded.dtype == np.uint8 and loaded.shape == (20, 30, 3)
    assert loaded[0, 0].tolist() == [200, 0, 0]
