"""A link cut from outside the controller: the fake UR behind a network namespace (or a TCP proxy), the
GRBL emulator's pty closed from the board's side; the watchdog that stops the arm; a clean reconnect.

The fake UR controllers here listen on their own addresses (a namespace's, or 127.0.0.3 behind the
proxy), never on 127.0.0.1's fixed ports: they do not collide with the other UR tests.
"""

from __future__ import annotations

import socket
import threading
import time

import pytest

from fgcd_drivers.testing.fake_ur_controller import SET_WATCHDOG, FakeController
from fgcd_drivers.testing.grbl_emulator import GrblEmulator
from fgcd_drivers.testing.link_cut import LinkUnavailable, NetnsLink, ProxyLink, netns_problem
from fgcd_drivers.ur import URConfig

pytestmark = pytest.mark.timeout(240)


def _skip_without_link(outcome) -> None:
    if outcome.detail.startswith("no cuttable link here"):
        pytest.skip(outcome.detail)


def test_the_stated_link_stop_time_is_the_watchdog_period_plus_one_kick():
    config = URConfig(host="x", watchdog_min_hz=2.0, watchdog_kick_s=0.05)
    assert config.link_stop_s == pytest.approx(0.55)
    assert URConfig(host="x", watchdog_min_hz=0.0).link_stop_s is None


def test_the_fake_controller_stops_its_program_when_the_watchdog_starves():
    ctrl = FakeController()
    ctrl.program_running, ctrl.reg_out_int[0] = True, 1
    ctrl.command({"input_int_register_0": SET_WATCHDOG, "input_double_register_0": 4.0})
    assert ctrl.watchdog_period_s == pytest.approx(0.25)
    ctrl.motion = (ctrl.T_base_flange.copy(), ctrl.T_base_flange.copy(), time.monotonic(), 60.0)
    assert not ctrl.check_watchdog()  # just updated
    ctrl.last_input -= 0.3  # no input package for longer than the period
    assert ctrl.check_watchdog()
    assert ctrl.motion is None and not ctrl.program_running and ctrl.watchdog_stops == 1
    assert ctrl.watchdog_period_s is None  # a program stop removes every watchdog


def test_a_kick_updates_the_watchdog_without_a_command_handshake():
    ctrl = FakeController()
    ctrl.program_running, ctrl.reg_out_int[0] = True, 1
    ctrl.command({"input_int_register_0": SET_WATCHDOG, "input_double_register_0": 1.0})
    ctrl.command({"input_int_register_0": 0})  # the client clears the command: ready again
    assert ctrl.reg_out_int[0] == 1
    ctrl.last_input -= 5.0
    ctrl.command({"input_int_register_0": 0})  # ur_rtde 1.6.5's kick
    assert not ctrl.check_watchdog() and ctrl.reg_out_int[0] == 1 and ctrl.cmd_state == "idle"


def test_the_proxy_cut_swallows_bytes_without_closing_the_connection():
    echo = socket.socket()
    echo.bind(("127.0.0.3", 0))
    echo.listen(1)
    port = echo.getsockname()[1]

    def serve() -> None:
        conn, _ = echo.accept()
        with conn:
            try:
                while data := conn.recv(1024):
                    conn.sendall(data)
            except OSError:
                pass  # the proxy closes its side at the end

    threading.Thread(target=serve, daemon=True).start()
    try:
        with ProxyLink(ports=(port,)) as link, socket.create_connection((link.address, port), timeout=5) as client:
            client.sendall(b"ping")
            assert client.recv(16) == b"ping"
            link.cut()
            client.sendall(b"lost")
            client.settimeout(0.5)
            with pytest.raises(socket.timeout):  # no answer, and no RST or FIN either
                client.recv(16)
    except LinkUnavailable as exc:
        pytest.skip(str(exc))
    finally:
        echo.close()


def test_a_namespace_cut_loses_packets_without_a_reset_and_is_removed():
    if netns_problem():
        pytest.skip(netns_problem())
    link = NetnsLink()
    try:
        link.open()
    except LinkUnavailable as exc:
        pytest.skip(str(exc))
    try:
        import subprocess
        import sys

        server = subprocess.Popen(
            [
                *link.prefix(),
                sys.executable,
                "-c",
                "import socket,sys\ns=socket.socket();s.bind((sys.argv[1],30004));s.listen(1)\n"
                "print('up',flush=True)\nc,_=s.accept()\nwhile c.recv(1024): c.sendall(b'x')\n",
                link.ns_ip,
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert server.stdout.readline().strip() == "up"
            with socket.create_connection((link.address, 30004), timeout=5) as client:
                client.sendall(b"a")
                assert client.recv(1) == b"x"
                link.cut()
                client.sendall(b"b")  # into the kernel's buffer: no error, as on a pulled cable
                client.settimeout(0.5)
                with pytest.raises(socket.timeout):
                    client.recv(1)
                link.restore()
                client.settimeout(30)
                assert client.recv(1) == b"x"  # TCP's retransmission delivers it once the cable is back
        finally:
            server.kill()
            server.wait()
    finally:
        link.close()
    names = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert link.name not in names


def test_a_connect_right_after_the_link_is_restored_reaches_the_peer():
    """A connect tried while the cable was out leaves the peer's neighbour entry failed; once ``restore``
    returns, a new connect gets through at once (no "No route to host" while the link comes back)."""
    if netns_problem():
        pytest.skip(netns_problem())
    link = NetnsLink()
    try:
        link.open()
    except LinkUnavailable as exc:
        pytest.skip(str(exc))
    try:
        import subprocess
        import sys

        server = subprocess.Popen(
            [
                *link.prefix(),
                sys.executable,
                "-c",
                "import socket,sys\ns=socket.socket();s.bind((sys.argv[1],30004));s.listen(4)\n"
                "print('up',flush=True)\nwhile True: s.accept()[0].close()\n",
                link.ns_ip,
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert server.stdout.readline().strip() == "up"
            link.cut()
            with pytest.raises(OSError):  # a timeout, or no route once the neighbour entry has failed
                socket.create_connection((link.address, 30004), timeout=4).close()
            link.restore()
            socket.create_connection((link.address, 30004), timeout=2).close()
        finally:
            server.kill()
            server.wait()
    finally:
        link.close()


def test_an_emulator_replugged_after_a_pull_keeps_its_alarm():
    with GrblEmulator() as emu:
        old = emu.port
        emu.inject_alarm(1)
        emu.unplug()
        new = emu.replug()
        assert new != old or emu.state == "Alarm"
        assert emu.state == "Alarm" and emu.alarm_code == 1


def test_a_network_cut_mid_move_stops_the_arm_and_a_reconnect_releases_nothing():
    from fgcd_cli.bench.faults.link_ur import STOP_MARGIN_S, ur_link_fault

    outcome = ur_link_fault("link_cut_ur_move", 0)  # seed 0: a protective stop raised during the cut
    _skip_without_link(outcome)
    assert outcome.extra["protective_during_cut"] is True
    assert outcome.ok, str(outcome.to_dict())
    assert outcome.code == 7 and outcome.stderr_lines == 1
    assert outcome.extra["arm_stopped_after_cut_s"] <= URConfig(host="x").link_stop_s + STOP_MARGIN_S
    assert outcome.extra["reconnect_code"] == 7  # the protective stop is reported, not released


def test_a_pulled_serial_cable_leaves_an_alarm_for_a_person_to_clear():
    from fgcd_cli.bench.faults.link_grbl import grbl_link_fault

    outcome = grbl_link_fault("link_cut_grbl_reconnect", 0)
    assert outcome.ok, str(outcome.to_dict())
    assert outcome.extra["alarm_during_cut"] in (1, 3)
    assert outcome.extra["reconnect_code"] == 7 and outcome.extra["refused_move_code"] == 7
    assert outcome.extra["home_code"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("fault,seed", [("link_cut_ur_idle", 1), ("link_cut_grbl_move", 0)])
def test_more_link_cuts_end_cleanly(fault, seed):
    from fgcd_cli.bench.faults.link_cuts import inject

    outcome = inject(fault, seed, None)
    _skip_without_link(outcome)
    assert outcome.ok, str(outcome.to_dict())


@pytest.mark.slow
def test_the_proxy_fallback_cuts_rtde_and_the_dashboard_alike():
    from fgcd_cli.bench.faults.link_ur import ur_link_fault

    outcome = ur_link_fault("link_cut_ur_move", 1, prefer="proxy")
    _skip_without_link(outcome)
    assert outcome.extra["link"] == "proxy"
    assert outcome.ok, str(outcome.to_dict())
