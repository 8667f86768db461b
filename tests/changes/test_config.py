"""The detector's configuration: its sections, the flat keyword options, the enums."""

import dataclasses
import json

import numpy as np
import pytest

from fgcd_cli.changes.config import OPTION_SECTION, DecisionRule, DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.region_decision import decide
from fgcd_cli.changes.regions import CueLabel
from fgcd_cli.changes.registration import RegistrationInit
from fgcd_cli.changes.tiled.pipeline import detect_changes_tiled
from fgcd_cli.errors import UserInputError
from fgcd_cli.metrics.afd import FdfConfig, FdfMethod


def _flat(config: DetectionConfig) -> dict:
    return {name: getattr(getattr(config, section), name) for name, section in OPTION_SECTION.items()}


def test_flat_options_replace_fields_of_their_section_only():
    config = DetectionConfig.from_options(k_high=14.0, dense=False, tile_px=512)
    assert config.regions.k_high == 14.0 and config.registration.dense is False and config.tiling.tile_px == 512
    assert _flat(config) == dict(_flat(DetectionConfig()), k_high=14.0, dense=False, tile_px=512)
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


def test_an_unknown_fdf_method_is_refused():
    with pytest.raises(UserInputError, match="unknown FDF method"):
        FdfConfig(method="orb")


def test_decide_takes_its_section():
    rng = np.random.default_rng(0)
    score = np.abs(rng.normal(size=(96, 96))).astype(np.float32)
    score[40:52, 40:52] += 30.0
    valid = np.ones(score.shape, bool)
    by_config = decide(
        score, valid, config=DetectionConfig.from_options(decision="hysteresis", k_high=14.0, k_low=7.0).regions
    )
    assert by_config[0][45, 45] and not by_config[0][5, 5]
    with pytest.raises(TypeError):
        decide(score, valid, k_high=14.0)
