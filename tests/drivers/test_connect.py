"""drivers/connect.py: the drivers by name and the one call form that opens a platform."""

import pytest

from fgcd_drivers.connect import DRIVERS, PlatformSpec, open_platform
from fgcd_drivers.manual import ManualPlatform


def test_platforms_open_in_one_call_form_with_their_options_in_a_spec():
    assert DRIVERS == ("sim", "grbl", "ur", "manual")
    manual = ManualPlatform()
    assert open_platform("sim", spec=PlatformSpec(sim_rig=manual, connect=False)) is manual
    with pytest.raises(TypeError):
        open_platform("sim", sim_rig=manual, connect=False)  # the options travel in the spec
    with pytest.raises(TypeError):
        PlatformSpec(sim_rigg=manual)
