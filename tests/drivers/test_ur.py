"""UR driver: the real ur_rtde client against the fake controller process.

The fake controller's ports are fixed (29999, 30003, 30004): these tests must
not run in parallel with each other (a pytest-xdist worker's fakes listen on its
own loopback address, ``conftest.UR_HOST``); every test kills its fake in a finally.
"""

from __future__ import annotations

import _thread
import json
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fgcd_core.platform import (
    GuardLimits,
    MotionGuard,
    MotionInterrupted,
    MotionRejected,
    PlatformConnectionError,
    PlatformTimeout,
    SafetyStop,
)
from fgcd_drivers.testing.fake_ur import FakeURProcess
from fgcd_drivers.ur import URConfig, URPlatform, abandoned_interface_count
from fgcd_drivers.ur_preflight import preflight
from fgcd_drivers.ur_state import pose_to_vector, safety_problem, vector_to_pose

from .conftest import UR_HOST

pytestmark = pytest.mark.timeout(90)

CONFIG = URConfig(host=UR_HOST, preflight_timeout_s=0.5, max_linear_speed_m_s=0.05, arrival_margin_s=1.0)


@pytest.fixture
def fake():
    process = FakeURProcess(host=UR_HOST)
    try:
        yield process.start()
    finally:
        process.stop()


@pytest.fixture
def arm(fake):
    platform = URPlatform(CONFIG)
    platform.connect()
    try:
        yield platform
    finally:
        platform.close()


def shifted(T, d_m):
    out = np.array(T)
    out[:3, 3] += d_m
    return out


def test_rotation_vector_round_trip_without_euler():
    rng = np.random.default_rng(4)
    for _ in range(20):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = rng.normal(size=3)
        np.testing.assert_allclose(vector_to_pose(pose_to_vector(T)), T, atol=1e-12)
    assert safety_problem(1) is None and safety_problem(1 | 4) == "protective stop"


def test_real_client_connects_reads_flange_pose_and_moves(arm):
    T0 = arm.flange_pose()
    # The fake's flange starts at (0.4, -0.1, 0.3), pointing down; its TCP offset
    # (5 cm) was zeroed at connect, so the reported pose is the flange's.
    np.testing.assert_allclose(T0[:3, 3], [0.4, -0.1, 0.3], atol=1e-9)
    target = shifted(T0, [0.01, -0.005, 0.0])
    target[:3, :3] = T0[:3, :3] @ Rotation.from_rotvec([0.0, 0.02, 0.0]).as_matrix()
    result = arm.move_to(target)
    np.testing.assert_allclose(result.T_base_flange_reached, target, atol=CONFIG.arrival_tolerance_m)
    assert result.duration_s >= 0.0112 / CONFIG.max_linear_speed_m_s * 0.9
    assert arm.describe()["healthy"]


def test_protective_stop_before_move_refuses(arm, fake):
    fake.send("protective_stop")
    time.sleep(0.05)
    T0 = arm.flange_pose()
    with pytest.raises(SafetyStop, match="protective stop"):
        arm.move_to(shifted(T0, [0.01, 0, 0]))
    np.testing.assert_allclose(arm.flange_pose(), T0)


def test_protective_stop_during_move_trips_guard_then_recovers(arm, fake):
    guard = MotionGuard(arm, GuardLimits(max_step_m=0.1, speed_fraction=0.5))
    T0 = arm.flange_pose()
    threading.Timer(0.3, fake.send, args=("protective_stop",)).start()
    with pytest.raises(SafetyStop, match="protective stop"):
        guard.move_to(shifted(T0, [0.05, 0, 0]))  # 2 s at 25 mm/s
    assert guard.tripped
    stopped = arm.flange_pose()
    assert 0.001 < stopped[0, 3] - T0[0, 3] < 0.04
    time.sleep(0.2)
    np.testing.assert_allclose(arm.flange_pose(), stopped)
    assert "releasing" in arm.unlock_protective_stop()
    time.sleep(0.05)
    guard.reset()
    guard.move_to(shifted(stopped, [0.002, 0, 0]))


def test_controller_gone_mid_move_is_connection_error_not_stale_pose(arm, fake):
    # The controller vanishes (power cut, cable pulled): the client's getters keep
    # the last values, the driver must refuse them.
    T0 = arm.flange_pose()
    threading.Timer(0.3, fake.stop).start()
    with pytest.raises(PlatformConnectionError, match="lost the connection|not running|failed"):
        arm.move_to(shifted(T0, [0.05, 0, 0]))
    with pytest.raises(PlatformConnectionError, match="stale|not connected"):
        arm.flange_pose()
    with pytest.raises(PlatformConnectionError, match="cannot reach"):
        arm.reconnect()


HUNG_SCRIPT = """
import json, os, sys, time
from fgcd_core.platform import GuardLimits, MotionGuard, PlatformConnectionError
from fgcd_drivers.ur import URConfig, URPlatform
arm = URPlatform(URConfig(host=sys.argv[1], preflight_timeout_s=0.5, max_linear_speed_m_s=0.05))
arm.connect()
arm.flange_pose()
print("READY", flush=True)
sys.stdin.readline()  # the test froze the controller
t_frozen = time.monotonic()
out = {"pose": "returned"}
# Poll rather than sleep a fixed time: on a loaded machine the freeze may take effect
# a little later; the pose must be refused within stale_after_s (0.5 s) plus that delay.
while time.monotonic() - t_frozen < 10.0:
    try:
        arm.flange_pose()
    except PlatformConnectionError as exc:
        out["pose"] = str(exc)
        break
    time.sleep(0.05)
out["refused_after_s"] = time.monotonic() - t_frozen
out["still_connected"] = arm._rtde_r.isConnected()
guard = MotionGuard(arm, GuardLimits(max_step_m=0.1))
t0 = time.monotonic()
try:
    guard.move_by(__import__("numpy").eye(4))
    out["move"] = "returned"
except PlatformConnectionError as exc:
    out["move"] = str(exc)
out["tripped"] = guard.tripped
t0 = time.monotonic()
arm.close()
out["close_s"] = time.monotonic() - t0
print(json.dumps(out), flush=True)
os._exit(0)  # ur_rtde's threads of a hung link would hold up a normal exit
"""


def test_hung_controller_state_is_stale_not_trusted(fake):
    # The controller stops streaming but keeps its sockets open (a hung controller, a
    # half-open link): isConnected() stays True and the getters repeat the last package.
    # Run in a child: ur_rtde's threads of a hung link keep reconnecting in native code
    # and must not share this test process with the next tests' clients.
    child = subprocess.Popen(
        [sys.executable, "-c", HUNG_SCRIPT, UR_HOST],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert child.stdout.readline().strip() == "READY"
        fake.send("freeze")
        child.stdin.write("go\n")
        child.stdin.flush()
        out, _ = child.communicate(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    result = json.loads(out.strip().splitlines()[-1])
    assert result["still_connected"] is True  # ur_rtde itself has not noticed
    assert "no fresh state" in result["pose"]
    assert result["refused_after_s"] < 5.0  # 0.5 s of staleness plus scheduling delays on a busy machine
    assert "no fresh state" in result["move"]  # refused before anything is sent
    assert result["close_s"] < 1.0  # close does not wait on the hung link


def test_arrival_timeout_stops_the_arm(arm, fake):
    fake.send("slow")  # the arm crawls at a tenth of the commanded speed
    guard = MotionGuard(arm, GuardLimits(max_step_m=0.1, speed_fraction=1.0))
    T0 = arm.flange_pose()
    t0 = time.monotonic()
    with pytest.raises(PlatformTimeout, match="did not arrive in time"):
        guard.move_to(shifted(T0, [0.02, 0, 0]))  # nominal 0.4 s, 4 s at the crawl
    # deadline: 1.5 x nominal + the 1 s margin, well before the crawl would arrive
    assert time.monotonic() - t0 < 3.0
    stopped = arm.flange_pose()
    time.sleep(0.3)
    np.testing.assert_allclose(arm.flange_pose(), stopped)  # stopL went out: no further motion
    assert stopped[0, 3] - T0[0, 3] < 0.015


def test_garbage_peer_is_refused_before_ur_rtde_touches_it():
    # Something else answers on the RTDE port (a web server, a wrong device).
    with socket.socket() as probe:
        if probe.connect_ex((UR_HOST, 30004)) == 0:
            pytest.skip("something else listens on 30004")
    server = socket.socket()
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind((UR_HOST, 30004))
    server.listen(1)

    def answer_garbage():
        conn, _ = server.accept()
        with conn:
            conn.recv(64)
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n\x00\xff")

    threading.Thread(target=answer_garbage, daemon=True).start()
    try:
        with pytest.raises(PlatformConnectionError, match="does not speak RTDE"):
            URPlatform(CONFIG).connect()
    finally:
        server.close()


def test_stop_from_another_thread_interrupts(arm):
    T0 = arm.flange_pose()
    threading.Timer(0.3, arm.stop).start()
    with pytest.raises(MotionInterrupted):
        arm.move_to(shifted(T0, [0.05, 0, 0]))
    stopped = arm.flange_pose()
    time.sleep(0.2)
    np.testing.assert_allclose(arm.flange_pose(), stopped)
    assert stopped[0, 3] - T0[0, 3] < 0.04


def test_ctrl_c_during_move_stops_arm(arm):
    guard = MotionGuard(arm, GuardLimits(max_step_m=0.1))
    T0 = arm.flange_pose()
    threading.Timer(0.3, _thread.interrupt_main).start()
    with pytest.raises(KeyboardInterrupt):
        guard.move_to(shifted(T0, [0.05, 0, 0]))
    stopped = arm.flange_pose()
    time.sleep(0.2)
    np.testing.assert_allclose(arm.flange_pose(), stopped)
    assert stopped[0, 3] - T0[0, 3] < 0.04 and "Ctrl-C" in guard.tripped


def test_outside_workspace_refused_before_moving(arm):
    guard = MotionGuard(arm, GuardLimits(max_step_m=0.1, workspace_max_m=(0.405, 1.0, 1.0)))
    T0 = arm.flange_pose()
    with pytest.raises(MotionRejected, match="outside the workspace"):
        guard.move_to(shifted(T0, [0.01, 0, 0]))
    np.testing.assert_allclose(arm.flange_pose(), T0)


def test_silent_peer_times_out_in_preflight_without_freezing():
    with FakeURProcess(host=UR_HOST, silent=True):
        t0 = time.monotonic()
        with pytest.raises(PlatformTimeout, match="did not answer"):
            URPlatform(CONFIG).connect()
        assert time.monotonic() - t0 < 3.0


def test_a_controller_that_answers_but_does_not_stream_times_out_in_preflight():
    # ur_rtde's receive constructor would wait for the first state package forever (GIL held).
    with FakeURProcess(host=UR_HOST) as fake:
        fake.send("freeze")
        t0 = time.monotonic()
        with pytest.raises(PlatformTimeout, match="sends no state"):
            URPlatform(CONFIG).connect()
        assert time.monotonic() - t0 < 3.0


def test_refused_port_is_connection_error():
    # Nothing listens on the RTDE port once the fake is gone.
    with socket.socket() as probe:
        if probe.connect_ex((UR_HOST, 30004)) == 0:
            pytest.skip("something else listens on 30004")
    with pytest.raises(PlatformConnectionError, match="cannot reach"):
        preflight(UR_HOST, timeout_s=0.5)


def test_stop_returns_even_when_ur_rtde_blocks_in_stopL():
    # ur_rtde can sit in its reconnect loop inside stopL for minutes when the controller is
    # gone; Ctrl-C and failure paths call stop() and must not hang with it.
    released = threading.Event()

    class BlockingControl:
        def isConnected(self):
            return True

        def isProgramRunning(self):
            return True

        def stopL(self, _acc):
            released.wait(30.0)

    arm = URPlatform(URConfig(host=UR_HOST, stop_timeout_s=0.3))
    arm._rtde_c = BlockingControl()
    t0 = time.monotonic()
    arm.stop()
    assert time.monotonic() - t0 < 2.0
    released.set()


# ----------------------------------------------------------------------------- abandoned interfaces
def test_abandoned_interfaces_are_counted(monkeypatch):
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
