"""The semi-dense depths of a keyframe are searched again when bundle adjustment moves its stereo geometry."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from fgcd_cli.vse import cloud as cloud_mod
from fgcd_cli.vse.cloud import SemiDenseCloud
from fgcd_cli.vse.types import VseConfig


def _engine(n: int, config: VseConfig) -> SimpleNamespace:
    kfs = []
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.01 * i
        kfs.append(SimpleNamespace(id=10 + i, T_cam_map=T, semidense=None, semidense_stereo=None))
    return SimpleNamespace(kfs=kfs, config=config)


def _searched(monkeypatch) -> list[tuple[int, tuple[int, ...]]]:
    calls: list[tuple[int, tuple[int, ...]]] = []

    def fake_search(eng, k, nbs):
        calls.append((k, tuple(nbs)))
        return SimpleNamespace(inv_depth=np.ones(3), generation=len(calls))

    monkeypatch.setattr(cloud_mod, "semidense_of_keyframe", fake_search)
    monkeypatch.setattr(
        cloud_mod, "depth_partners", lambda eng, k: [j for j in (k - 1, k + 1) if 0 <= j < len(eng.kfs)]
    )
    return calls


def test_a_keyframe_whose_partner_moved_is_searched_again_with_the_same_partners(monkeypatch):
    calls = _searched(monkeypatch)
    eng = _engine(4, VseConfig())
    SemiDenseCloud._update_depths(eng)
    assert calls == [(1, (0, 2)), (2, (1, 3))]  # the first and the newest keyframe lack a partner on one side
    first = eng.kfs[1].semidense
    # nothing moved: nothing is searched again
    SemiDenseCloud._update_depths(eng)
    assert len(calls) == 2
    # bundle adjustment moves keyframe 0, a partner of keyframe 1 only
    eng.kfs[0].T_cam_map = eng.kfs[0].T_cam_map.copy()
    eng.kfs[0].T_cam_map[1, 3] += 1e-4
    SemiDenseCloud._update_depths(eng)
    assert calls[2:] == [(1, (0, 2))]
    assert eng.kfs[1].semidense is not first
    SemiDenseCloud._update_depths(eng)
    assert len(calls) == 3


def test_without_the_refresh_depths_are_searched_once(monkeypatch):
    calls = _searched(monkeypatch)
    eng = _engine(4, VseConfig(semidense_refresh=False))
    SemiDenseCloud._update_depths(eng)
    eng.kfs[2].T_cam_map = eng.kfs[2].T_cam_map.copy()
    eng.kfs[2].T_cam_map[1, 3] += 1e-4
    SemiDenseCloud._update_depths(eng)
    assert [k for k, _ in calls] == [1, 2]


def test_a_search_that_fails_again_keeps_the_depths_found_before(monkeypatch):
    calls = _searched(monkeypatch)
    eng = _engine(4, VseConfig())
    SemiDenseCloud._update_depths(eng)
    kept = eng.kfs[1].semidense
    monkeypatch.setattr(cloud_mod, "semidense_of_keyframe", lambda eng, k, nbs: None)
    eng.kfs[1].T_cam_map = eng.kfs[1].T_cam_map.copy()
    eng.kfs[1].T_cam_map[2, 3] += 1e-4
    SemiDenseCloud._update_depths(eng)
    assert eng.kfs[1].semidense is kept
    assert len(calls) == 2
