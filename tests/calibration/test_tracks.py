"""calibration/handeye/tracks.py: which views the target-free refinement matches."""

from fgcd_cli.calibration.handeye.tracks import pair_list


def test_pairs_follow_the_match_window_and_the_anchors():
    assert pair_list(4) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    assert pair_list(6, 1, anchors=(0, 3, 5, 9)) == [(0, 1), (0, 3), (0, 5), (1, 2), (2, 3), (3, 4), (3, 5), (4, 5)]
