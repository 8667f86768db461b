"""Renovation seams (#20): config dataclasses keep the old defaults, the GRBL grammar is pure."""

from __future__ import annotations

import math

import pytest

from fgcd_drivers.connect import DRIVERS, PlatformSpec, open_platform
from fgcd_drivers.grbl.protocol import (
    GrblState,
    LineKind,
    alarm_text,
    classify_line,
    parse_setting,
    parse_status,
)
from fgcd_drivers.manual import ManualPlatform
from fgcd_drivers.ur import abandoned_interface_count


def test_platforms_open_in_one_call_form_with_their_options_in_a_spec():
    assert DRIVERS == ("sim", "grbl", "ur", "manual")
    manual = ManualPlatform()
    assert open_platform("sim", spec=PlatformSpec(sim_rig=manual, connect=False)) is manual
    with pytest.raises(TypeError):
        open_platform("sim", sim_rig=manual, connect=False)  # the options travel in the spec
    with pytest.raises(TypeError):
        PlatformSpec(sim_rigg=manual)


def test_ur_abandoned_accessor(monkeypatch):
    import fgcd_drivers.ur as ur

    monkeypatch.setattr(ur, "_ABANDONED", [])
    assert abandoned_interface_count() == 0
    ur._ABANDONED.append((None, None))
    assert abandoned_interface_count() == 1


def test_interfaces_abandoned_before_a_command_do_not_end_the_host_process(monkeypatch, capsys):
    # A test session (or any host) in which a UR link was abandoned earlier: a later
    # in-process command must return through SystemExit, not os._exit the host.
    import fgcd_drivers.ur as ur
    from fgcd_cli.cli import app as cli_app

    monkeypatch.setattr(ur, "_ABANDONED", [(None, None)])
    monkeypatch.setattr(cli_app.os, "_exit", lambda code: pytest.fail(f"os._exit({code}) ended the host process"))
    monkeypatch.setattr(cli_app.sys, "argv", ["fgcd", "sim", "scenes", "--json"])
    with pytest.raises(SystemExit) as exc:
        cli_app.main()
    assert exc.value.code in (0, None)


def test_a_command_that_abandons_interfaces_ends_its_process_at_once(monkeypatch):
    import fgcd_drivers.ur as ur
    from fgcd_cli.cli import app as cli_app

    monkeypatch.setattr(ur, "_ABANDONED", [])
    exits = []

    def run_abandoning(_app, _args):
        ur._ABANDONED.append((None, None))  # what URPlatform.close does on a hung or dropped link
        return 7

    monkeypatch.setattr(cli_app, "run", run_abandoning)
    monkeypatch.setattr(cli_app.os, "_exit", exits.append)
    monkeypatch.setattr(cli_app.sys, "argv", ["fgcd", "platform", "check"])
    with pytest.raises(SystemExit):
        cli_app.main()
    assert exits == [7]


def test_grbl_line_classes():
    assert classify_line("") is LineKind.EMPTY
    assert classify_line("ok") is LineKind.ANSWER
    assert classify_line("error:20") is LineKind.ANSWER
    assert classify_line("okay") is LineKind.NOISE
    assert classify_line("<Idle|MPos:0,0,0|FS:0,0>") is LineKind.STATUS
    assert classify_line("ALARM:2") is LineKind.ALARM
    assert classify_line("Grbl 1.1h ['$' for help]") is LineKind.BANNER
    assert classify_line("[MSG:Caution: Unlocked]") is LineKind.MESSAGE
    assert classify_line("$110=500.000") is LineKind.SETTING
    assert parse_setting("$130=-2.5") == (130, -2.5)
    assert alarm_text(0).startswith("GRBL Alarm (alarm state)")
    assert alarm_text(2).startswith("GRBL ALARM:2 (soft limit")


def test_grbl_status_parsing_keeps_wco_for_wpos():
    wco = {"X": 0.0, "Y": 0.0, "Z": 0.0}
    status, wco = parse_status("<Idle|MPos:1,2,3|FS:0,0|WCO:0.5,0.25,0>", "XYZ", wco, received_at=1.0)
    assert status.state == GrblState.IDLE == "Idle" and status.mpos == {"X": 1.0, "Y": 2.0, "Z": 3.0}
    status, wco = parse_status("<Hold:0|WPos:1,2,3|F:100>", "XYZ", wco, received_at=2.0)
    assert (status.state, status.substate, status.feed_mm_min) == ("Hold", 0, 100.0)
    assert status.mpos == {"X": 1.5, "Y": 2.25, "Z": 3.0}
    assert parse_status("<Idle|FS:0,0>", "XYZ", wco, received_at=3.0)[0] is None
    assert parse_status("<Idle|MPos:a,b,c>", "XYZ", wco, received_at=3.0)[0] is None


def test_a_sim_platform_takes_its_config_and_refuses_four_axes():
    from fgcd_drivers.sim.platform import SimFault, SimPlatform, SimPlatformConfig

    p = SimPlatform(config=SimPlatformConfig(dof=3, timeout_s=3.0))
    assert (p.dof, p.timeout_s, p.rotation_rad_per_s) == (3, 3.0, math.radians(5.0))
    with pytest.raises(ValueError):
        SimPlatform(config=SimPlatformConfig(dof=4))
    assert [f.value for f in SimFault] == ["timeout", "estop", "disconnect"]
