"""Edge tolerance: differences a sub-pixel relocation residual explains at strong edges are not changes."""

import cv2
import numpy as np
import pytest

from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.cues.maps import edge_band, edge_tolerant_difference, envelope_distance, shift_tolerant_difference
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.metrics.change_scores import binary_scores

from .conftest import textured_scene

SCALE = 4  # scenes are drawn 4x finer, then area-sampled like a camera pixel


def _revisit(image: np.ndarray) -> np.ndarray:
    """The same scene seen again: exposure 0.9x, a small offset."""
    return np.clip(image * 0.9 + 0.03, 0, 1)


def _niche_scene(shift_fine_px: int = 0, stain: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Textured wall with a thin dark groove (a niche's side wall seen edge-on) and a bright step edge.

    ``shift_fine_px`` moves the edges by that many fine pixels (1/4 px in the image):
    a relocation residual's parallax at depth edges. Returns the image and the stain truth.
    """
    size = 256
    texture = cv2.resize(textured_scene(size), (size * SCALE, size * SCALE), interpolation=cv2.INTER_LINEAR)
    fine = 0.35 + 0.3 * texture
    x0 = 100 * SCALE + 1 + shift_fine_px
    fine[:, x0 : x0 + 3] = (
        0.05  # groove 0.75 px wide: area sampling makes its contrast depend on the sub-pixel position
    )
    fine[:, 180 * SCALE + 2 + shift_fine_px :] += 0.3  # a bright step (the niche's lit front face)
    truth_fine = np.zeros(fine.shape, np.uint8)
    if stain:
        cv2.circle(truth_fine, (108 * SCALE, 128 * SCALE), 6 * SCALE, 1, -1)  # 6 px radius, 2 px off the groove
        fine[truth_fine > 0] = 0.9
    image = cv2.resize(np.clip(fine, 0, 1).astype(np.float32), (size, size), interpolation=cv2.INTER_AREA)
    truth = cv2.resize(truth_fine.astype(np.float32), (size, size), interpolation=cv2.INTER_AREA) > 0.5
    return image, truth


def test_envelope_distance_is_zero_inside_the_neighbourhood_range():
    other = np.array([[0.0, 0.2, 0.4], [0.1, 0.5, 0.3], [0.2, 0.2, 0.2]], np.float32)
    image = np.full((3, 3), 0.45, np.float32)
    assert envelope_distance(image, other, radius_px=1)[1, 1] == 0.0
    image[1, 1] = 0.7
    assert np.isclose(envelope_distance(image, other, radius_px=1)[1, 1], 0.2)


def test_half_pixel_shift_of_a_thin_edge_is_explained():
    ref, _ = _niche_scene(0)
    cur, _ = _niche_scene(2)  # half a pixel
    plain = shift_tolerant_difference(ref, cur, radius_px=1)
    tolerant = edge_tolerant_difference(ref, cur, radius_px=1, edge_radius_px=2)
    groove = np.s_[20:-20, 97:104]
    assert plain[groove].max() > 0.1  # the groove's contrast changes: integer shifts cannot explain it
    assert tolerant[groove].max() < 0.02
    assert edge_band(ref)[:, 100].all()


def test_half_pixel_shifted_edge_is_not_a_change():
    ref, _ = _niche_scene(0)
    cur, _ = _niche_scene(2)
    # the pixel-level tolerance alone (the contrast floor would also set these faint bands aside)
    result = detect_changes(
        [ref], [_revisit(cur)], config=DetectionConfig.from_options(edge_tolerance_px=2, min_contrast=0.0)
    )
    assert result.comparable, result.reason
    assert result.regions == []
    without = detect_changes([ref], [_revisit(cur)], config=DetectionConfig.from_options(min_contrast=0.0))
    assert len(without.regions) > 0  # the situation the tolerance is for


@pytest.mark.parametrize(
    "setting,min_recall",
    [
        ({"edge_tolerance_px": 2}, 0.6),
        # the pixel-level tolerance trims the stain's pixels inside the band; the region check keeps them all
        ({"edge_check_px": 2}, 0.8),
    ],
)
def test_stain_next_to_an_edge_is_still_found(setting, min_recall):
    ref, _ = _niche_scene(0)
    cur, truth = _niche_scene(2, stain=True)
    result = detect_changes([ref], [_revisit(cur)], config=DetectionConfig.from_options(**setting))
    assert result.comparable, result.reason
    assert len(result.regions) == 1
    scores = binary_scores(result.mask, truth)
    assert scores.recall > min_recall and scores.precision > 0.6


# -- region-level edge check (what `fgcd diff` on a campaign uses)


def test_edge_check_sets_the_shifted_groove_aside_and_keeps_it_visible():
    ref, _ = _niche_scene(0)
    cur, _ = _niche_scene(2)
    result = detect_changes([ref], [_revisit(cur)], config=DetectionConfig.from_options(edge_check_px=2))
    assert result.comparable, result.reason
    assert result.regions == []
    assert result.settings["edge_explained_regions"] >= 1
    assert result.edge_explained is not None and result.edge_explained[:, 97:104].any()  # shown, not lost


def test_edge_check_keeps_a_new_thin_crack_away_from_reference_edges():
    ref, _ = _niche_scene(0)
    cur, _ = _niche_scene(2)
    cur = cur.copy()
    cur[60:200, 140:142] = 0.05  # a new 2 px dark crack across the texture, away from the groove and the step
    truth = np.zeros(ref.shape, bool)
    truth[60:200, 139:143] = True
    plain = detect_changes([ref], [_revisit(cur)])
    assert any(r.bbox_xywh[0] > 130 for r in plain.regions)  # the plain detector finds it (and the groove)
    result = detect_changes([ref], [_revisit(cur)], config=DetectionConfig.from_options(edge_check_px=2))
    assert len(result.regions) == 1
    assert binary_scores(result.mask, truth).recall > 0.8


def test_edge_check_off_by_default():
    ref, _ = _niche_scene(0)
    cur, _ = _niche_scene(2)
    result = detect_changes([ref], [_revisit(cur)])
    assert result.edge_explained is None and "edge_explained_regions" not in result.settings
