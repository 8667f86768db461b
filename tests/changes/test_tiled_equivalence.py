"""The tiled detector's fast paths compute what the shared helpers compute (same values, or float32 rounding)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage
from skimage.morphology import reconstruction

from fgcd_cli.changes.cues.maps import _min_shifted_difference, shift_tolerant_difference
from fgcd_cli.changes.extent import grow_to_extent
from fgcd_cli.changes.illumination import normalize_local_gain, prepare_gain_weight
from fgcd_cli.changes.regions import extract_regions, regions_with_significance
from fgcd_cli.changes.significance import AcontrarioConfig, acontrario_decision
from fgcd_cli.changes.tiled.geometry import tile_grid
from fgcd_cli.changes.tiled.schedule import median_float16, run_tiles
from fgcd_cli.changes.tiled.tile_scores import TiledScore

RNG_SEED = 7


def _grow_by_reconstruction(seeds, score, valid, *, background, fraction):
    """Reference for ``grow_to_extent``: a morphological reconstruction per seed, in the same window."""
    if fraction <= 0 or not seeds.any():
        return seeds & valid
    excess = np.maximum(score.astype(np.float32) - np.float32(background), 0.0)
    labels, count = ndimage.label(seeds, structure=np.ones((3, 3), bool))
    peaks = ndimage.maximum(excess, labels, np.arange(1, count + 1))
    out = np.zeros_like(seeds)
    h, w = seeds.shape
    for i, (window, peak) in enumerate(zip(ndimage.find_objects(labels), peaks)):
        pad = max(8, int(max(window[0].stop - window[0].start, window[1].stop - window[1].start)))
        y0, y1 = max(0, window[0].start - pad), min(h, window[0].stop + pad)
        x0, x1 = max(0, window[1].start - pad), min(w, window[1].stop + pad)
        seed = labels[y0:y1, x0:x1] == i + 1
        allowed = (excess[y0:y1, x0:x1] >= fraction * peak) & valid[y0:y1, x0:x1]
        core = seed & allowed
        if not core.any():
            core = seed
        out[y0:y1, x0:x1] |= reconstruction(
            core.astype(np.uint8), (allowed | core).astype(np.uint8), method="dilation"
        ).astype(bool)
    return out & valid


def _regions_by_extraction(mask, score, significance, pixel_area_mm2):
    """Reference for ``regions_with_significance``: the shared region extraction, then each seed's NFA."""
    regions, labels = extract_regions(mask, score, pixel_area_mm2=pixel_area_mm2)
    for region in regions:
        inside = significance.seed_index[labels == region.id]
        inside = np.unique(inside[inside > 0])
        if inside.size:
            region.log10_nfa = float(min(significance.regions[i - 1].log10_nfa for i in inside))
    return regions, labels


def _texture(shape, rng) -> np.ndarray:
    """Smooth random texture in [0, 1], float32."""
    return np.clip(cv2.GaussianBlur(rng.random(shape, dtype=np.float32), (0, 0), 1.5) * 1.6 - 0.3, 0, 1)


def _score_with_blobs(rng, shape=(300, 360)):
    score = cv2.GaussianBlur(rng.random(shape, dtype=np.float32), (0, 0), 2.0)
    for _ in range(12):
        y, x, r = rng.integers(10, shape[0] - 10), rng.integers(10, shape[1] - 10), rng.integers(2, 9)
        cv2.circle(score, (int(x), int(y)), int(r), float(rng.uniform(1.5, 4.0)), -1)
    score = cv2.GaussianBlur(score, (0, 0), 1.0)
    valid = np.ones(shape, bool)
    valid[:, :6] = False
    return score, valid


def test_symmetric_shift_difference_is_the_larger_of_the_two_one_sided_minima():
    rng = np.random.default_rng(RNG_SEED)
    for shape in [(70, 90, 3), (41, 33), (5, 4, 3)]:
        for quantised in (False, True):
            ref, cur = rng.random(shape, dtype=np.float32), rng.random(shape, dtype=np.float32)
            if quantised:  # many ties between shifts
                ref, cur = np.round(ref * 8) / 8, np.round(cur * 8) / 8
            for radius in (1, 2):
                two_passes = np.maximum(
                    _min_shifted_difference(ref, cur, radius), _min_shifted_difference(cur, ref, radius)
                )
                np.testing.assert_array_equal(shift_tolerant_difference(ref, cur, radius_px=radius), two_passes)
    # Row-strided views are read as they are.
    ref, cur = rng.random((60, 80, 3), dtype=np.float32), rng.random((60, 80, 3), dtype=np.float32)
    np.testing.assert_array_equal(
        shift_tolerant_difference(ref[5:50, 7:70], cur[5:50, 7:70]),
        shift_tolerant_difference(ref[5:50, 7:70].copy(), cur[5:50, 7:70].copy()),
    )


@pytest.mark.parametrize("shape", [(400, 420, 3), (380, 300)])
def test_gain_on_a_region_with_a_shared_weight_equals_the_whole_image_gain(shape):
    rng = np.random.default_rng(RNG_SEED)
    ref = _texture(shape, rng)
    ramp = np.linspace(0.7, 1.1, shape[1], dtype=np.float32)[None, :]
    cur = np.clip(ref * (ramp[:, :, None] if len(shape) == 3 else ramp) + 0.01, 0, 1).astype(np.float32)
    weight = np.ones(shape[:2], np.float32)
    weight[120:260, 150:300] = 0  # a large suspect area: the wide window takes over inside it
    weight[10:14, 10:14] = 0
    region = (slice(60, 340), slice(0, 380))
    for w in (None, weight):
        whole = normalize_local_gain(ref, cur, sigma_px=12.0, weight=w)
        prepared = None if w is None else prepare_gain_weight(w, 12.0, ref.shape, region=region)
        assert prepared is None or prepared.window is not None
        part = normalize_local_gain(ref, cur, sigma_px=12.0, weight=prepared, region=region)
        assert part.shape == whole[region].shape and part.dtype == np.float32
        np.testing.assert_allclose(part, whole[region], rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="prepared"):  # a weight prepared for another region
        normalize_local_gain(
            ref, cur, sigma_px=12.0, weight=prepare_gain_weight(weight, 12.0, ref.shape), region=region
        )


def test_grow_to_extent_equals_a_reconstruction_per_seed():
    rng = np.random.default_rng(RNG_SEED)
    score, valid = _score_with_blobs(rng)
    seeds = score > np.quantile(score[valid], 0.995)
    for fraction in (0.0, 0.3, 0.6):
        np.testing.assert_array_equal(
            grow_to_extent(seeds, score, valid, background=float(np.median(score)), fraction=fraction),
            _grow_by_reconstruction(seeds, score, valid, background=float(np.median(score)), fraction=fraction),
        )
    empty = np.zeros_like(seeds)
    np.testing.assert_array_equal(grow_to_extent(empty, score, valid, background=0.5, fraction=0.3), empty)


def test_regions_from_the_mask_pixels_equal_the_extracted_ones():
    rng = np.random.default_rng(RNG_SEED)
    score, valid = _score_with_blobs(rng)
    decision = acontrario_decision(
        score,
        valid,
        config=AcontrarioConfig(epsilon=1.0, seed_p=0.005, extent_fraction=0.3),
        min_cluster_area_px=4 * np.pi * 4,
    )
    mask = decision.mask.copy()
    mask[50:53, 50:80] = True  # a region without a seed
    area = np.full(score.shape, 0.04)
    area[:, :100] = np.nan
    for pixel_area in (None, area):
        fast, fast_labels = regions_with_significance(mask, score, decision, pixel_area)
        shared, shared_labels = _regions_by_extraction(mask, score, decision, pixel_area)
        assert fast == shared
        np.testing.assert_array_equal(fast_labels, shared_labels)
    assert any(r.log10_nfa is None for r in fast) and any(r.log10_nfa is not None for r in fast)
    assert regions_with_significance(np.zeros_like(mask), score, decision, None)[0] == []


def test_float16_median_is_numpys():
    rng = np.random.default_rng(RNG_SEED)
    for size in (1, 2, 7, 1000, 1001):
        values = (rng.random(size) * 3).astype(np.float16)
        assert median_float16(values) == float(np.median(values.astype(np.float32)))
    signed = np.array([-1.0, 0.5, 2.0, -0.25], np.float16)
    assert median_float16(signed) == float(np.median(signed.astype(np.float32)))


def test_run_tiles_prepares_each_tile_once_and_reports_in_order():
    tiles = tile_grid((300, 400), 100, 10)
    prepared, worked, finished = [], [], []

    def prepare(tile):
        prepared.append(tile.index)
        return tile.index * 10

    def work(tile, context, k):
        assert context == tile.index * 10
        worked.append((tile.index, k))

    for workers in (1, 2):
        prepared.clear(), worked.clear(), finished.clear()
        run_tiles(tiles, 3, prepare, work, lambda tile: finished.append(tile.index), workers)
        assert sorted(prepared) == list(range(len(tiles)))
        assert sorted(worked) == [(t, k) for t in range(len(tiles)) for k in range(3)]
        assert finished == list(range(len(tiles)))

    def failing(tile, context, k):
        if tile.index == 2:
            raise RuntimeError("tile 2 failed")

    with pytest.raises(RuntimeError, match="tile 2"):
        run_tiles(tiles, 3, prepare, failing, lambda tile: None, 2)


def test_first_pass_reads_only_the_narrow_reach_and_later_passes_the_overlap():
    tiles = tile_grid((1000, 1200), 400, 147)
    shape = (1000, 1200)
    scorer = TiledScore.__new__(TiledScore)
    scorer.shape, scorer.gain_sigma_px, scorer.shift_radius_px = shape, 12.0, 1
    reach = 48 + 1  # the 97-tap kernel's half width and the shift
    for tile in tiles:
        y0, y1, x0, x1 = scorer._read_box(tile, 0)
        cy0, cy1, cx0, cx1 = tile.core
        assert (y0, y1, x0, x1) == (
            max(0, cy0 - reach),
            min(shape[0], cy1 + reach),
            max(0, cx0 - reach),
            min(shape[1], cx1 + reach),
        )
        assert scorer._read_box(tile, 1) == tile.ext


def test_labels_of_regions_match_a_fresh_labelling():
    # regions_with_significance relabels by area like extract_regions: a sanity check on ties.
    mask = np.zeros((40, 40), bool)
    mask[2:5, 2:5] = mask[10:13, 30:33] = mask[30:34, 5:9] = True  # two of 9 px, one of 16 px
    score = np.ones(mask.shape, np.float32)

    class NoSeeds:
        seed_index = None

    regions, labels = regions_with_significance(mask, score, NoSeeds(), None)
    assert [r.area_px for r in regions] == [16, 9, 9]
    assert [r.bbox_xywh[:2] for r in regions] == [(5, 30), (2, 2), (30, 10)]  # ties in raster order
    assert ndimage.label(labels > 0)[1] == 3
