import cv2
import numpy as np
import pytest

from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.regions import pixel_area_from_depth
from fgcd_cli.errors import UserInputError
from fgcd_cli.metrics.change_scores import binary_scores

from .conftest import textured_scene, translate


def test_finds_the_injected_change_in_reference_frame(scene_pair):
    result = detect_changes([scene_pair["ref"]], [scene_pair["cur"]])
    assert result.comparable, result.reason
    scores = binary_scores(result.mask, scene_pair["truth"])
    # The disc is 450 px; its rim is blurred by the 2 px score smoothing and the
    # 1 px shift tolerance, so a band of ~2 px around 75 px of perimeter is uncertain.
    assert scores.iou > 0.6
    assert result.regions[0].id == 1
    cx, cy = result.regions[0].centroid_xy
    assert abs(cx - 170) < 3 and abs(cy - 90) < 3


def test_unchanged_pair_gives_no_large_region():
    ref = textured_scene()
    cur = np.clip(translate(ref, -1.2, 0.7) * 0.8 + 0.05, 0, 1)
    result = detect_changes([ref], [cur])
    assert result.comparable
    assert result.changed_fraction < 0.002
    assert all(r.area_px < 100 for r in result.regions)


def test_metric_area_from_depth(scene_pair):
    # Fronto-parallel plane at 0.5 m with f = 1000 px: each pixel sees 0.5 mm x 0.5 mm.
    K = np.array([[1000.0, 0, 128], [0, 1000.0, 128], [0, 0, 1]])
    area = pixel_area_from_depth(np.full((256, 256), 0.5), K)
    assert np.allclose(area[5:-5, 5:-5], 0.25, rtol=1e-6)
    result = detect_changes([scene_pair["ref"]], [scene_pair["cur"]], pixel_area_mm2=area)
    region = result.regions[0]
    assert region.area_mm2 == pytest.approx(region.area_px * 0.25, rel=1e-3)


def test_several_lightings_and_16_bit_input(scene_pair):
    ref, cur = scene_pair["ref"], scene_pair["cur"]
    refs = [ref, np.clip(ref * 0.6, 0, 1)]
    curs = [cur, np.clip(cur * 0.6, 0, 1)]
    as16 = lambda ims: [np.round(im * 65535).astype(np.uint16) for im in ims]  # noqa: E731
    r8 = detect_changes(refs, curs)
    r16 = detect_changes(as16(refs), as16(curs))
    assert r16.comparable
    assert binary_scores(r16.mask, r8.mask).iou > 0.9


def test_different_sizes_is_a_user_error(scene_pair):
    with pytest.raises(UserInputError, match="same size"):
        detect_changes([scene_pair["ref"]], [scene_pair["cur"][:200]])


def test_lighting_count_mismatch_is_a_user_error(scene_pair):
    with pytest.raises(UserInputError, match="one current image per reference lighting"):
        detect_changes([scene_pair["ref"]] * 2, [scene_pair["cur"]])


def test_black_image_cannot_be_compared(scene_pair):
    result = detect_changes([scene_pair["ref"]], [np.zeros_like(scene_pair["cur"])])
    assert not result.comparable
    assert "black" in result.reason
    assert not result.mask.any()


def test_textureless_image_cannot_be_compared(scene_pair):
    result = detect_changes([scene_pair["ref"]], [np.full_like(scene_pair["cur"], 0.5)])
    assert not result.comparable
    assert "texture" in result.reason


def test_no_overlap_cannot_be_compared():
    big = cv2.resize(textured_scene(512), (512, 512))
    ref = big[:, :256].copy()
    cur = big[:, 256:].copy()  # the other half of the wall: nothing in common
    result = detect_changes([ref], [cur])
    assert not result.comparable
    assert "cannot compare" in result.reason
