"""The grouped option sections keep the former flat defaults, names and string values."""

from __future__ import annotations

import inspect
import json
import math
from dataclasses import replace

import numpy as np
import pytest

from fgcd_cli.alignment import FastAlignConfig
from fgcd_cli.alignment.fast_config import ColdStartConfig, IcpMetric, RobustKernel, SearchScore, WeakProbeConfig
from fgcd_cli.alignment.health import HealthEvidence, HealthLimits, assess
from fgcd_cli.alignment.initial import GuessSource
from fgcd_cli.alignment.results import HEALTH_OK, StartPath
from fgcd_cli.alignment.synthetic import SessionConfig, make_session

#: Flat option name of the former single-level config -> (section, field), the record of the grouping.
FORMER_NAMES: dict[str, tuple[str, str]] = {
    "level_points": ("levels", "points"),
    "level_radius_rel": ("levels", "radius_rel"),
    "level_iterations": ("levels", "iterations"),
    "level_metric": ("levels", "metric"),
    "robust": ("rigid", "robust"),
    "sparse_p": ("rigid", "sparse_p"),
    "admm_iterations": ("rigid", "admm_iterations"),
    "inlier_factor": ("rigid", "inlier_factor"),
    "min_inlier_spacing": ("rigid", "min_inlier_spacing"),
    "estimate_scale": ("scale", "estimate"),
    "scale_from_level": ("scale", "from_level"),
    "max_scale_step": ("scale", "max_step"),
    "max_scale_drift": ("scale", "max_drift"),
    "trim_factor": ("scale", "trim_factor"),
    "tau_T": ("convergence", "tau_T"),
    "tau_sigma": ("convergence", "tau_sigma"),
    "stall_rel": ("convergence", "stall_rel"),
    "warm_rel": ("warm", "rel"),
    "warm_max_scale_change": ("warm", "max_scale_change"),
    "warm_max_rotation_deg": ("warm", "max_rotation_deg"),
    "warm_check_scale_change": ("warm", "check_scale_change"),
    "scale_candidates": ("cold", "scale_candidates"),
    "search_score": ("cold", "search_score"),
    "scale_refinements": ("cold", "scale_refinements"),
    "search_iterations": ("cold", "search_iterations"),
    "shift_steps": ("cold", "shift_steps"),
    "shift_rel": ("cold", "shift_rel"),
    "shift_points": ("cold", "shift_points"),
    "shift_radius_rel": ("cold", "shift_radius_rel"),
    "shift_iterations": ("cold", "shift_iterations"),
    "minimum_check_step": ("minimum_check", "step"),
    "minimum_check_margin": ("minimum_check", "margin"),
    "minimum_check_iterations": ("minimum_check", "iterations"),
    "health_points": ("health", "points"),
    "inlier_rel": ("health", "inlier_rel"),
    "inlier_noise_factor": ("health", "inlier_noise_factor"),
    "overlap_rel": ("health", "overlap_rel"),
    "min_inlier_ratio": ("health", "min_inlier_ratio"),
    "min_overlap": ("health", "min_overlap"),
    "min_condition_ratio": ("health", "min_condition_ratio"),
    "condition_noise_factor": ("health", "condition_noise_factor"),
    "scale_bounds": ("health", "scale_bounds"),
    "weak_probe": ("probe", "enabled"),
    "weak_probe_rel": ("probe", "rel"),
    "weak_probe_directions": ("probe", "directions"),
    "weak_probe_return": ("probe", "return_fraction"),
    "weak_probe_points": ("probe", "points"),
    "weak_probe_iterations": ("probe", "iterations"),
}

#: The defaults of the flat FastAlignConfig before the grouping (issue #20).
OLD_DEFAULTS = dict(
    tau_T=1e-4, tau_sigma=1e-5, estimate_scale=True, robust="sparse", sparse_p=0.4, admm_iterations=1,
    level_points=(1500, 5000, 8000), health_points=10000, level_radius_rel=(math.inf, 0.2, 0.06),
    level_iterations=(60, 20, 40), level_metric=("point", "plane", "plane"), scale_from_level=1,
    max_scale_step=0.02, max_scale_drift=0.12, inlier_factor=3.0, min_inlier_spacing=2.0, trim_factor=3.0,
    inlier_rel=0.01, inlier_noise_factor=3.0, overlap_rel=0.05, min_inlier_ratio=0.6, min_overlap=0.3,
    min_condition_ratio=5e-3, condition_noise_factor=3.0, weak_probe=True, weak_probe_rel=0.01,
    weak_probe_directions=3, weak_probe_return=0.5, weak_probe_points=3000, weak_probe_iterations=15,
    scale_bounds=(1 / 1.5, 1.5), stall_rel=0.005, warm_rel=0.02, warm_max_scale_change=0.03,
    warm_max_rotation_deg=3.0, warm_check_scale_change=0.02, scale_candidates=(0.8, 0.9, 1.0, 1.1, 1.25),
    search_score="median", scale_refinements=2, search_iterations=(40, 10), minimum_check_step=0.04,
    minimum_check_margin=0.03, minimum_check_iterations=8, shift_steps=2, shift_rel=0.06, shift_points=600,
    shift_radius_rel=0.1, shift_iterations=12, seed=0,
)


def test_fast_config_keeps_every_flat_default_in_its_section():
    config = FastAlignConfig()
    assert set(FORMER_NAMES) | {"seed"} == set(OLD_DEFAULTS)
    for name, value in OLD_DEFAULTS.items():
        section, key = FORMER_NAMES.get(name, (None, name))
        assert getattr(config if section is None else getattr(config, section), key) == value, name


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


def test_session_config_keeps_the_keyword_defaults():
    defaults = SessionConfig()
    assert (defaults.n_keyframes, defaults.distance, defaults.baseline, defaults.pose_noise_deg,
            defaults.pose_noise_m, defaults.depth_noise_rel, defaults.points_per_keyframe, defaults.centre) == (
        6, 0.6, 0.08, 0.15, 0.0015, 0.003, 4000, (0.0, 0.0))
    assert "n_keyframes" not in inspect.signature(make_session).parameters  # now a SessionConfig field


def test_assess_reports_every_failed_check_in_order():
    d = np.r_[np.full(60, 0.001), np.full(40, 0.5)]
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-1, 1, (200, 2)), np.zeros(200)])
    normals = np.tile([0.0, 0.0, 1.0], (200, 1))
    evidence = HealthEvidence(distances=d, matched_points=pts, matched_normals=normals, converged=False, scale=2.0)
    limits = HealthLimits(inlier_threshold=0.01, overlap_threshold=0.02, min_inlier_ratio=0.7, min_overlap=0.3,
                          min_condition_ratio=5e-3, scale_bounds=(0.5, 1.5))
    health = assess(evidence, limits)
    assert not health.ok and health.degenerate
    assert health.reason.startswith("did not converge; inlier ratio 60% < 70%; degenerate geometry")
    assert health.reason.endswith("scale changed by a factor 2.000, outside [0.500, 1.500]")
    good = assess(replace(evidence, converged=True, scale=1.0), replace(limits, min_inlier_ratio=0.5,
                                                                        min_condition_ratio=0.0))
    assert good.ok and good.reason == HEALTH_OK
