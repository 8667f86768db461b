"""A region's brightness change and tone against synthetic truth."""

import numpy as np
import pytest

from fgcd_cli.changes.regions import ChangeRegion, set_brightness_changes


def _region(region_id: int, area: int) -> ChangeRegion:
    return ChangeRegion(
        id=region_id, area_px=area, area_mm2=None, bbox_xywh=(0, 0, 1, 1), centroid_xy=(0, 0), mean_score=1, max_score=1
    )


def test_a_stain_reads_darker_a_relief_change_mixed_and_swapping_flips_the_value():
    shape = (40, 60)
    labels = np.zeros(shape, np.int32)
    labels[5:15, 5:15] = 1  # a stain: 30 % darker under every light
    labels[20:30, 30:50] = 2  # relief: brighter under the first light, darker under the second
    refs = [np.full(shape, 0.5, np.float32), np.full(shape, 0.4, np.float32), np.full(shape, 0.6, np.float32)]
    curs = [r.copy() for r in refs]
    for k, cur in enumerate(curs):
        cur[labels == 1] *= 0.7 * (1 + 0.01 * k)  # the lightings agree, with a little scatter
        cur[labels == 2] *= (1.25, 0.8, 1.0)[k]
    regions = [_region(1, 100), _region(2, 200)]
    set_brightness_changes(regions, labels, refs, curs)
    assert regions[0].tone == "darker" and regions[0].brightness_change == pytest.approx(-0.3, abs=0.01)
    assert regions[1].tone == "mixed"
    swapped = [_region(1, 100), _region(2, 200)]
    set_brightness_changes(swapped, labels, curs, refs)
    assert swapped[0].tone == "brighter"
    assert (1 + swapped[0].brightness_change) * (1 + regions[0].brightness_change) == pytest.approx(1.0)
