"""The relocation's modes, stages, sources, actions and agreement: the strings written to logs and JSON."""

from fgcd_cli.relocation.enums import Agreement, CoarseAction, EstimateSource, EstimateStage, LoopMode


def test_enum_values_are_the_logged_strings():
    assert [m.value for m in LoopMode] == ["parallel", "serial"]
    assert [s.value for s in EstimateStage] == ["fast", "fine", "image"]
    assert [s.value for s in EstimateSource] == ["image", "3d", ""]
    assert [a.value for a in CoarseAction] == ["move", "descend", "look", "handover", "pause"]
    assert Agreement.NOT_CHECKED.because("no image stage") == "not checked: no image stage"
    assert f"{EstimateSource.THREE_D} estimate" == "3d estimate" and EstimateStage.IMAGE == "image"
