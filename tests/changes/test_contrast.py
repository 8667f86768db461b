"""Region contrast and the contrast floor: a change fainter than the floor is not reported, however clean the pair."""

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.config import MIN_REGION_CONTRAST, DetectionConfig
from fgcd_cli.changes.contrast import region_contrasts, set_contrasts
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.regions import ChangeRegion
from fgcd_cli.report.candidates import contrast_text, faint_text

from .conftest import textured_scene


def _discs(shape, centres, radius):
    labels = np.zeros(shape, np.int32)
    for k, (x, y) in enumerate(centres, start=1):
        cv2.circle(labels, (x, y), radius, k, -1)
    return labels


def test_contrast_is_the_relative_change_at_its_strongest():
    ref = np.full((120, 200), 0.5, np.float32)
    labels = _discs(ref.shape, [(50, 60), (150, 60)], 12)
    cur = ref.copy()
    cur[labels == 1] = 0.35  # darker
    cur[labels == 2] = 0.6  # brighter
    contrast = region_contrasts(labels, 2, refs=[ref], normalized=[cur])
    # |change| over the mean of the two brightnesses; a disc 12 px across keeps its full step at
    # its centre under the 1 px averaging.
    np.testing.assert_allclose(contrast, [0.15 / 0.425, 0.1 / 0.55], atol=0.005)
    # swapping the observations gives the same contrast
    np.testing.assert_allclose(region_contrasts(labels, 2, refs=[cur], normalized=[ref]), contrast, atol=1e-9)


def test_contrast_takes_the_strongest_lighting_and_channel():
    ref = np.full((80, 80, 3), 0.4, np.float32)
    labels = _discs(ref.shape[:2], [(40, 40)], 10)
    unchanged = ref.copy()
    tinted = ref.copy()
    tinted[labels == 1] = (0.5, 0.4, 0.3)  # warmer: red up, blue down, about the same luma
    contrast = region_contrasts(labels, 1, refs=[ref, ref], normalized=[unchanged, tinted])
    np.testing.assert_allclose(contrast, [0.1 / 0.35], atol=0.005)  # blue: 0.4 -> 0.3
    regions = [
        ChangeRegion(
            id=1, area_px=1, area_mm2=None, bbox_xywh=(0, 0, 1, 1), centroid_xy=(40, 40), mean_score=1.0, max_score=1.0
        )
    ]
    set_contrasts(regions, labels, [ref, ref], [unchanged, tinted])
    assert regions[0].contrast == pytest.approx(contrast[0]) and regions[0].lightings == (2,)


def _stained_pair(darkening: float):
    """Gravel texture; the current image has a round stain ``darkening`` (0.05: 5 %) darker, and
    sensor noise far below a real revisit's (1/1000 of full scale): a pair as clean as a simulated one."""
    ref = 0.2 + 0.6 * textured_scene(256)
    truth = _discs(ref.shape, [(128, 128)], 9) > 0
    cur = ref.copy()
    cur[truth] *= 1.0 - darkening
    rng = np.random.default_rng(3)
    noisy = [np.clip(im + rng.normal(0.0, 0.001, im.shape), 0, 1).astype(np.float32) for im in (ref, cur)]
    return noisy[0], noisy[1], truth


@pytest.mark.parametrize(
    "darkening, reported", [(0.05, False), (0.4, True)], ids=["5 % (a quarter of the floor)", "40 % (twice it)"]
)
def test_floor_sets_aside_faint_regions_only(darkening, reported):
    assert MIN_REGION_CONTRAST == pytest.approx(0.2)
    ref, cur, truth = _stained_pair(darkening)
    # Without the floor the clean pair's own null finds even the faint stain.
    unfloored = detect_changes([ref], [cur], config=DetectionConfig.from_options(min_contrast=0.0))
    assert any(
        truth[r.bbox_xywh[1] + r.bbox_xywh[3] // 2, r.bbox_xywh[0] + r.bbox_xywh[2] // 2] for r in unfloored.regions
    )
    result = detect_changes([ref], [cur])
    hits = [r for r in result.regions if truth[int(r.centroid_xy[1]), int(r.centroid_xy[0])]]
    assert bool(hits) == reported
    if not reported:
        assert result.settings["low_contrast_regions"] >= 1
        # and the report and the command line say so
        assert "contrast below 20 % in every lighting" in faint_text(result.settings)
        # set aside, not lost: the report's candidates list it first
        first = result.candidates[0]
        assert truth[int(first.centroid_xy[1]), int(first.centroid_xy[0])]


def test_contrast_text_names_the_lightings_that_show_it():
    assert contrast_text(0.42, (1, 3), 4) == "42 % (lightings 1, 3 of 4)"
    assert contrast_text(0.3, (2,), 4) == "30 % (lighting 2 of 4)"
    assert contrast_text(0.95, (1,), 1) == "95 %"  # one lighting: nothing to name
    assert contrast_text(None, None) == ""
