"""`fgcd_cli.app.rig_options`: each rig value from the option, else campaign.toml [rig], else the default."""

import pytest

from fgcd_cli.app.rig_options import EffectiveRig, RigOptions, check_campaign_rig, check_record_rig, resolve_rig
from fgcd_cli.campaign.store import init_campaign
from fgcd_cli.errors import CampaignError, UserInputError


def test_an_option_wins_over_the_campaign_which_wins_over_the_default(tmp_path):
    camp = init_campaign(
        tmp_path / "c", site="x", rig={"driver": "grbl", "port": "/dev/ttyUSB0", "baud": 57600, "camera": "/dev/video2"}
    )
    assert resolve_rig(camp, RigOptions()) == EffectiveRig(
        driver="grbl", port="/dev/ttyUSB0", baud=57600, camera="/dev/video2"
    )
    given = resolve_rig(camp, RigOptions(port="/dev/ttyACM0", baud=9600, camera="1"))
    assert (given.port, given.baud, given.camera) == ("/dev/ttyACM0", 9600, 1)
    assert resolve_rig(None, RigOptions()) == EffectiveRig(driver="sim", baud=115200, camera=0)
    assert resolve_rig(None, RigOptions(driver="ur", host="h")).driver_given


def test_bad_values_are_refused_before_anything_opens(tmp_path):
    with pytest.raises(UserInputError, match="--port"):
        resolve_rig(None, RigOptions(driver="grbl"))
    with pytest.raises(UserInputError, match="--baud"):
        resolve_rig(None, RigOptions(baud=-5))
    with pytest.raises(UserInputError, match="--camera"):
        resolve_rig(None, RigOptions(camera=" "))
    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "sim", "baud": "fast"})
    with pytest.raises(CampaignError, match=r"\[rig\] baud"):
        resolve_rig(camp, RigOptions())


def test_a_campaign_is_one_rig(tmp_path):
    camp = init_campaign(tmp_path / "c", site="x", rig={"driver": "ur", "host": "10.0.0.5"})
    ur = resolve_rig(camp, RigOptions())
    check_campaign_rig(camp, ur, what="a hand-eye")  # the campaign's own rig, another address is fine too
    check_campaign_rig(camp, resolve_rig(camp, RigOptions(host="10.0.0.6")), what="a hand-eye")
    with pytest.raises(UserInputError, match="ur rig"):
        check_campaign_rig(camp, resolve_rig(camp, RigOptions(driver="sim")), what="a hand-eye")
    check_record_rig({"T_flange_cam": []}, ur, name="handeye", command="c")  # older records say nothing: kept
    with pytest.raises(CampaignError, match="made on the sim rig"):
        check_record_rig({"driver": "sim"}, ur, name="handeye", command="c")
    assert ur.record() == {"driver": "ur", "host": "10.0.0.5", "camera": 0}
