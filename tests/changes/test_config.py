"""The detector's configuration: sections with the historical defaults, the flat keyword options, the enums."""

import dataclasses
import json

import numpy as np
import pytest

from fgcd_cli.changes.baseline_iccv import ICCV2015Config
from fgcd_cli.changes.config import OPTION_SECTION, DecisionRule, DetectionConfig
from fgcd_cli.changes.dense import DenseConfig, smoothing_scale_px
from fgcd_cli.changes.detect import decide, detect_changes
from fgcd_cli.changes.photometric import JointFitConfig
from fgcd_cli.changes.regions import CueLabel
from fgcd_cli.changes.registration import RegistrationInit
from fgcd_cli.changes.significance import AcontrarioConfig
from fgcd_cli.changes.tiled import detect_changes_tiled
from fgcd_cli.errors import UserInputError
from fgcd_cli.metrics.afd import FdfConfig, FdfMethod

# The keyword defaults of detect_changes / detect_changes_tiled before the options were grouped.
OLD_DEFAULTS = dict(
    register=True, gain_sigma_px=12.0, shift_radius_px=1, structure_weight=0.0, smooth_sigma_px=2.0, k_high=20.0,
    k_low=10.0, min_region_px=30, max_hole_px=30, registration_lighting=0, robust_gain_rounds=1, edge_fraction=0.2,
    edge_radius_px=6, edge_tolerance_px=0, edge_contrast=3.0, edge_check_px=0, edge_check_band_fraction=0.8,
    decision="acontrario", epsilon=1.0, seed_p=0.005, extent_fraction=0.3, dense=True, cues=True, ambient_index=0,
    light_dirs=None, tile_px=2048, overlap_px=None, work_px=1600, workers=2, decision_px=1000,
)
# Options added after the grouping, with their defaults.
OLD_DEFAULTS["fine_smooth_sigma_px"] = 1.0


def _flat(config: DetectionConfig) -> dict:
    return {name: getattr(getattr(config, section), name) for name, section in OPTION_SECTION.items()}


def test_sections_hold_every_old_option_with_its_old_default():
    assert _flat(DetectionConfig()) == OLD_DEFAULTS


def test_flat_options_replace_fields_of_their_section_only():
    config = DetectionConfig.from_options(k_high=14.0, dense=False, tile_px=512)
    assert config.regions.k_high == 14.0 and config.registration.dense is False and config.tiling.tile_px == 512
    assert _flat(config) == dict(OLD_DEFAULTS, k_high=14.0, dense=False, tile_px=512)
    again = DetectionConfig.from_options(config, k_low=5.0)
    assert again.regions.k_high == 14.0 and again.regions.k_low == 5.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.regions.k_high = 1.0


def test_unknown_options_and_rules_are_refused():
    with pytest.raises(TypeError, match="nonsense"):
        DetectionConfig.from_options(nonsense=1)
    with pytest.raises(UserInputError, match="unknown decision rule"):
        DetectionConfig.from_options(decision="otsu")
    image = np.zeros((8, 8), np.float32)
    with pytest.raises(TypeError):
        detect_changes([image], [image], k_high=14.0)  # options go in the config, not beside it
    with pytest.raises(UserInputError, match="edge_check_px is not supported tile by tile"):
        detect_changes_tiled([image], [image], config=DetectionConfig.from_options(edge_check_px=2))
    with pytest.raises(UserInputError, match="not supported tile by tile"):
        detect_changes_tiled([image], [image], config=DetectionConfig.from_options(structure_weight=0.5))


def test_enums_keep_their_string_values():
    assert DetectionConfig.from_options(decision="hysteresis").regions.decision is DecisionRule.HYSTERESIS
    assert [str(v) for v in CueLabel] == ["relief", "colour", "both"]
    assert [str(v) for v in DecisionRule] == ["hysteresis", "acontrario"]
    assert [str(v) for v in RegistrationInit] == ["sift", "identity", "none"]
    assert [str(v) for v in FdfMethod] == ["sift", "grid", "pairs"]
    assert json.dumps({"cue": CueLabel.BOTH, "init": RegistrationInit.SIFT}) == '{"cue": "both", "init": "sift"}'
    assert CueLabel.RELIEF == "relief" and f"{CueLabel.COLOUR}" == "colour"


def test_other_configs_keep_the_old_keyword_defaults():
    assert dataclasses.asdict(DenseConfig()) == dict(
        max_flow_px=5.0, smooth_px=smoothing_scale_px(), fb_px=1.0, robust_px=1.0, robust_iterations=3,
        texture_half=0.016, normalise_px=4.0, order=2)
    assert dataclasses.asdict(FdfConfig()) == dict(
        method="sift", ratio=0.75, ransac_px=3.0, max_features=4000, min_inliers=12, grid_cells=8, patch_px=96,
        min_response=0.1)
    assert dataclasses.asdict(AcontrarioConfig()) == dict(
        epsilon=1.0, seed_p=0.005, extent_fraction=0.2, level_step=0.25, max_candidates=5, area_rounds=3,
        null_rounds=2, score_maps=1)
    assert dataclasses.asdict(ICCV2015Config()) == dict(
        n_normal_bins=16, rank=3, spatial_sigma_px=40.0, sparse_threshold=2.0, smooth_sigma_px=2.0)
    assert dataclasses.asdict(JointFitConfig()) == dict(
        shadow_fraction=0.2, falloff_sigma_px=40.0, same_lights=True, align=True)
    with pytest.raises(UserInputError, match="unknown FDF method"):
        FdfConfig(method="orb")


def test_decide_takes_its_section():
    rng = np.random.default_rng(0)
    score = np.abs(rng.normal(size=(96, 96))).astype(np.float32)
    score[40:52, 40:52] += 30.0
    valid = np.ones(score.shape, bool)
    by_config = decide(score, valid, config=DetectionConfig.from_options(
        decision="hysteresis", k_high=14.0, k_low=7.0).regions)
    assert by_config[0][45, 45] and not by_config[0][5, 5]
    with pytest.raises(TypeError):
        decide(score, valid, k_high=14.0)
