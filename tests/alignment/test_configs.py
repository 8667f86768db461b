"""The grouped option sections are the one way to set an option; modes and statuses keep their strings; health."""

from __future__ import annotations

import inspect
import json
from dataclasses import replace

import numpy as np
import pytest

from fgcd_cli.alignment.fast_config import (
    ColdStartConfig,
    FastAlignConfig,
    IcpMetric,
    RobustKernel,
    SearchScore,
    WeakProbeConfig,
)
from fgcd_cli.alignment.health import HealthEvidence, HealthLimits, assess
from fgcd_cli.alignment.initial import GuessSource
from fgcd_cli.alignment.results import HEALTH_OK, StartPath
from fgcd_cli.alignment.synthetic import make_session


def test_sections_are_the_one_way_to_set_an_option():
    config = FastAlignConfig(cold=ColdStartConfig(shift_steps=0), probe=WeakProbeConfig(enabled=False), seed=3)
    assert config.cold.shift_steps == 0 and config.probe.enabled is False and config.seed == 3
    assert config.rigid.robust is RobustKernel.SPARSE and config.levels.iterations == (60, 20, 40)
    with pytest.raises(TypeError):
        FastAlignConfig(shift_steps=0)  # a former flat name
    with pytest.raises(AttributeError):
        _ = config.shift_steps


def test_modes_and_statuses_keep_their_string_values():
    assert FastAlignConfig().levels.metric == ("point", "plane", "plane")
    assert all(isinstance(m, IcpMetric) for m in FastAlignConfig().levels.metric)
    assert FastAlignConfig().cold.search_score == "median" and SearchScore("truncated") is SearchScore.TRUNCATED
    assert [str(p) for p in StartPath] == ["warm", "warm, checked", "warm -> cold", "cold"]
    encoded = json.dumps([StartPath.WARM_TO_COLD, GuessSource.FIRST_CAMERA_FAST])
    assert encoded == '["warm -> cold", "first_camera+fast"]'
    assert f"{GuessSource.GLOBAL}" == "global"


def test_the_synthetic_session_takes_its_options_as_a_session_config():
    assert "n_keyframes" not in inspect.signature(make_session).parameters  # now a SessionConfig field


def test_assess_reports_every_failed_check_in_order():
    d = np.r_[np.full(60, 0.001), np.full(40, 0.5)]
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-1, 1, (200, 2)), np.zeros(200)])
    normals = np.tile([0.0, 0.0, 1.0], (200, 1))
    evidence = HealthEvidence(distances=d, matched_points=pts, matched_normals=normals, converged=False, scale=2.0)
    limits = HealthLimits(
        inlier_threshold=0.01,
        overlap_threshold=0.02,
        min_inlier_ratio=0.7,
        min_overlap=0.3,
        min_condition_ratio=5e-3,
        scale_bounds=(0.5, 1.5),
    )
    health = assess(evidence, limits)
    assert not health.ok and health.degenerate
    assert health.reason.startswith("did not converge; inlier ratio 60% < 70%; degenerate geometry")
    assert health.reason.endswith("scale changed by a factor 2.000, outside [0.500, 1.500]")
    good = assess(
        replace(evidence, converged=True, scale=1.0), replace(limits, min_inlier_ratio=0.5, min_condition_ratio=0.0)
    )
    assert good.ok and good.reason == HEALTH_OK
