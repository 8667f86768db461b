"""A fake Universal Robots controller for the real ``ur_rtde`` client, run as its own process.

``python -m drivers.testing.fake_ur [--host 127.0.0.1] [--silent]`` listens on the
controller's fixed ports: RTDE 30004, dashboard 29999 and the script port 30003.
It prints ``READY`` on stdout once listening and takes fault-injection commands
on stdin, one per line:

``protective_stop``  raise safety bit 2 and halt the motion (moveL returns False)
``emergency_stop``   raise safety bit 7 (robot emergency stop)
``clear``            clear the safety bits (like unlocking the protective stop)
``disconnect``       close every RTDE connection now (the client's isConnected() goes False;
                     the dashboard and script connections stay, like a dropped RTDE link)
``disconnect_first`` close only the oldest RTDE connection (the receive interface's)
``silent``           from now on accept connections but never answer
``freeze``           stop sending RTDE data packages on the open connections, which stay
                     open (a hung controller or a half-open link: the client's getters go stale)
``slow``             the arm moves at a tenth of the commanded speed (it does not arrive in time)
``quit``             exit

What it speaks (RTDE protocol v2, big-endian, ``uint16 size | uint8 type | payload``):
the version handshake, output and input recipes with the types of UR's RTDE
variable table, data packages at 125 Hz (it claims a CB3 controller 3.15 so the
client picks 125 Hz), and ur_rtde's command handshake through the registers:
``output_int_register_0`` is 1 when ready for a command and 2 when the command
in ``input_int_register_0`` is done; the client then clears the command. Moves
are straight lines at the requested speed (no acceleration phase).

There is no installable URSim or RTDE server on PyPI and URSim needs Docker, so
this small stand-in is written by hand. It runs in a separate process because
the ur_rtde constructors hold the GIL: a fake in the same interpreter would
freeze with its client.
"""

from __future__ import annotations

import argparse
import math
import socket
import struct
import sys
import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003

_V6 = "VECTOR6D"
_OUTPUT_TYPES = {
    "timestamp": "DOUBLE", "target_q": _V6, "target_qd": _V6, "target_qdd": _V6, "target_current": _V6,
    "target_moment": _V6, "actual_q": _V6, "actual_qd": _V6, "actual_current": _V6,
    "joint_control_output": _V6, "actual_TCP_pose": _V6, "actual_TCP_speed": _V6, "actual_TCP_force": _V6,
    "target_TCP_pose": _V6, "target_TCP_speed": _V6, "actual_digital_input_bits": "UINT64",
    "joint_temperatures": _V6, "actual_execution_time": "DOUBLE", "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32", "safety_mode": "INT32", "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D", "speed_scaling": "DOUBLE", "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE", "actual_main_voltage": "DOUBLE", "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE", "actual_joint_voltage": _V6, "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32", "elbow_position": "VECTOR3D", "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32", "safety_status_bits": "UINT32", "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE", "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE", "standard_analog_output1": "DOUBLE", "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32", "euromap67_output_bits": "UINT32", "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE", "tool_mode": "UINT32", "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE", "tool_analog_input1": "DOUBLE", "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE", "tool_temperature": "DOUBLE", "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32", "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE", "payload_cog": "VECTOR3D", "payload_inertia": _V6, "script_control_line": "UINT32",
    "ft_raw_wrench": _V6, "joint_position_deviation_ratio": _V6, "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "INT32", "actual_digital_output_bits_": "UINT64",
    "tool_output_mode": "UINT8", "tool_digital_output0_mode": "UINT8", "tool_digital_output1_mode": "UINT8",
    "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE", "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8", "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8", "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
    "external_force_torque": _V6,
}
_FORMATS = {
    "DOUBLE": ">d", "VECTOR6D": ">6d", "VECTOR3D": ">3d", "INT32": ">i", "UINT32": ">I", "UINT64": ">Q",
    "UINT8": ">B", "BOOL": ">?", "VECTOR6INT32": ">6i", "VECTOR6UINT32": ">6I",
}


def _type_of(name: str) -> str:
    if name in _OUTPUT_TYPES:
        return _OUTPUT_TYPES[name]
    if name.startswith(("output_int_register_", "input_int_register_")):
        return "INT32"
    if name.startswith(("output_double_register_", "input_double_register_")):
        return "DOUBLE"
    if name.startswith(("output_bit_register_", "input_bit_register_")):
        return "BOOL"
    return "NOT_FOUND"


def _pose_to_T(pose) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(pose[3:6]).as_matrix()
    T[:3, 3] = pose[:3]
    return T


def _T_to_pose(T) -> list[float]:
    return [*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_rotvec()]


class FakeController:
    """The robot's state and its motion, shared by the servers."""

    def __init__(self) -> None:
        self.lock = threading.RLock()
        # Flange pose in the base frame and the active TCP offset (flange -> tcp).
        self.T_base_flange = _pose_to_T([0.4, -0.1, 0.3, math.pi, 0.0, 0.0])
        self.T_flange_tcp = _pose_to_T([0.0, 0.0, 0.05, 0.0, 0.0, 0.0])
        self.safety_bits = 1  # bit 0: normal mode
        self.robot_mode = 7  # running
        self.program_running = False
        self.reg_out_int = [0] * 48
        self.reg_out_double = [0.0] * 48
        self.cmd_state = "idle"  # idle -> busy -> done
        self.motion = None  # (start T, end T, start time, duration)
        self.speed = np.zeros(6)
        self.silent = False
        self.frozen = False
        self.speed_factor = 1.0
        self.connections: list[socket.socket] = []
        self.t0 = time.monotonic()
        self.done_at: float | None = None
        self.log = None  # a text stream to trace commands (--trace)

    # ------------------------------------------------------------------ motion
    def step(self) -> None:
        with self.lock:
            if self.cmd_state == "busy" and self.done_at is not None and time.monotonic() >= self.done_at:
                self.cmd_state = "done"
                self.reg_out_int[0] = 2
                self.done_at = None
            if self.motion is None:
                self.speed = np.zeros(6)
                return
            start, end, t_start, duration = self.motion
            frac = 1.0 if duration <= 0 else min(1.0, (time.monotonic() - t_start) / duration)
            rot = Slerp([0.0, 1.0], Rotation.from_matrix([start[:3, :3], end[:3, :3]]))([frac])
            T = np.eye(4)
            T[:3, :3] = rot.as_matrix()[0]
            T[:3, 3] = start[:3, 3] + frac * (end[:3, 3] - start[:3, 3])
            self.T_base_flange = T
            if frac >= 1.0:
                self.motion = None
                self.speed = np.zeros(6)
                if self.cmd_state == "busy" and self.done_at is None:
                    self.done_at = time.monotonic() + 0.01
            else:
                v = (end[:3, 3] - start[:3, 3]) / duration
                self.speed = np.concatenate([v, np.zeros(3)])

    def halt(self) -> None:
        with self.lock:
            self.motion = None
            self.speed = np.zeros(6)

    # ------------------------------------------------------------------ commands
    def command(self, values: dict[str, float | int]) -> None:
        """A data package of an input recipe: ur_rtde's command protocol."""
        cmd = int(values.get("input_int_register_0", 0))
        if self.log is not None:
            print(f"{time.monotonic() - self.t0:.3f} cmd {cmd} reg0={self.reg_out_int[0]} {self.cmd_state}", file=self.log, flush=True)
        with self.lock:
            if cmd == 0:
                # The client clears the command: the script is ready for the next one.
                if self.program_running and (self.cmd_state == "done" or self.done_at is not None
                                             or self.safety_bits & ~1):
                    self.cmd_state = "idle"
                    self.reg_out_int[0] = 1
                    self.done_at = None
                return
            if self.cmd_state != "idle" or not self.program_running:
                return
            d = [float(values.get(f"input_double_register_{i}", 0.0)) for i in range(18)]
            if self.safety_bits & ~1 and cmd not in (33, 34, 255):
                return  # protective/emergency stop: commands are not executed
            # Like UR's control script: results are written first and "done" is
            # signalled a few cycles later (ur_rtde reads the result registers as
            # soon as it sees done, so they must already be in an earlier package).
            self.cmd_state = "busy"
            self.reg_out_int[0] = 0
            self.done_at = time.monotonic() + 0.02
            if cmd == 3:  # moveL(pose, speed, acceleration, async)
                asynchronous = int(values.get("input_int_register_1", 0)) == 1
                T_base_tcp_target = _pose_to_T(d[0:6])
                end = T_base_tcp_target @ np.linalg.inv(self.T_flange_tcp)
                start = self.T_base_flange.copy()
                dist = float(np.linalg.norm(end[:3, 3] - start[:3, 3]))
                angle = float(np.linalg.norm(Rotation.from_matrix(start[:3, :3].T @ end[:3, :3]).as_rotvec()))
                speed = max(d[6] * self.speed_factor, 1e-6)
                duration = max(dist / speed, angle / max(speed * 10.0, 1e-6))
                self.motion = (start, end, time.monotonic(), duration)
                if not asynchronous:
                    self.done_at = None  # done when the motion ends
            elif cmd in (33, 34):  # stopL / stopJ
                self.halt()
            elif cmd == 29:  # setTcp
                self.T_flange_tcp = _pose_to_T(d[0:6])
            elif cmd == 40:  # getTCPOffset
                self.reg_out_double[0:6] = _T_to_pose(self.T_flange_tcp)
            elif cmd == 58:  # getActualToolFlangePose
                self.reg_out_double[0:6] = _T_to_pose(self.T_base_flange)
            elif cmd == 255:  # stopScript
                self.halt()
                self.program_running = False
                self.reg_out_int[0] = 0
                self.cmd_state = "idle"
                self.done_at = None
            # anything else: acknowledged as done without effect

    def set_safety(self, bits: int) -> None:
        with self.lock:
            self.safety_bits = bits
            if bits & ~1:
                self.halt()
                # A protective stop aborts the program's current command.

    # ------------------------------------------------------------------ state
    def outputs(self, name: str):
        with self.lock:
            T_tcp = self.T_base_flange @ self.T_flange_tcp
            if name == "timestamp":
                return time.monotonic() - self.t0
            if name in ("actual_TCP_pose", "target_TCP_pose"):
                return _T_to_pose(T_tcp)
            if name in ("actual_TCP_speed", "target_TCP_speed"):
                return list(self.speed)
            if name == "robot_mode":
                return self.robot_mode
            if name == "safety_mode":
                return 3 if self.safety_bits & 4 else (7 if self.safety_bits & 0xE0 else 1)
            if name == "safety_status":
                return 3 if self.safety_bits & 4 else (7 if self.safety_bits & 0xE0 else 1)
            if name == "safety_status_bits":
                return self.safety_bits
            if name == "runtime_state":
                return 2 if self.program_running else 1
            if name == "robot_status_bits":
                # bit 0 power on, bit 1 program running
                return 1 | (2 if self.program_running else 0)
            if name.startswith("output_int_register_"):
                return self.reg_out_int[int(name.rsplit("_", 1)[1])]
            if name.startswith("output_double_register_"):
                return self.reg_out_double[int(name.rsplit("_", 1)[1])]
            if name == "speed_scaling" or name == "target_speed_fraction":
                return 1.0
            kind = _type_of(name)
            if kind.startswith("VECTOR6"):
                return [0] * 6
            if kind == "VECTOR3D":
                return [0.0] * 3
            return 0


# ----------------------------------------------------------------------------- RTDE
def _recv_exact(conn: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise ConnectionError("peer closed")
        data += chunk
    return data


def _send_packet(conn: socket.socket, kind: bytes, payload: bytes) -> None:
    conn.sendall(struct.pack(">HB", 3 + len(payload), kind[0]) + payload)


def _pack(kind: str, value) -> bytes:
    fmt = _FORMATS[kind]
    if kind.startswith("VECTOR"):
        return struct.pack(fmt, *value)
    if kind in ("DOUBLE",):
        return struct.pack(fmt, float(value))
    return struct.pack(fmt, int(value))


def _serve_rtde(ctrl: FakeController, conn: socket.socket) -> None:
    outputs: list[str] = []
    output_types: list[str] = []
    inputs: dict[int, tuple[list[str], list[str]]] = {}
    frequency = 125.0
    started = threading.Event()
    send_lock = threading.Lock()

    last_logged = [None]

    def sender() -> None:
        period = 1.0 / min(frequency, 125.0)
        while started.is_set():
            if ctrl.frozen:
                time.sleep(period)
                continue
            ctrl.step()
            try:
                payload = b"\x01" + b"".join(_pack(t, ctrl.outputs(n)) for n, t in zip(outputs, output_types))
            except Exception as exc:  # noqa: BLE001 - a fake must say why it stopped
                print(f"fake_ur sender failed: {exc!r}", file=sys.stderr, flush=True)
                raise
            if ctrl.log is not None and "output_int_register_0" in outputs:
                state = (ctrl.reg_out_int[0], round(ctrl.reg_out_double[0], 3))
                if state != last_logged[0]:
                    last_logged[0] = state
                    print(f"{time.monotonic() - ctrl.t0:.3f} sent reg0={state[0]} d0={state[1]}", file=ctrl.log, flush=True)
            try:
                with send_lock:
                    _send_packet(conn, b"U", payload)
            except OSError:
                return
            time.sleep(period)

    try:
        while True:
            size, kind = struct.unpack(">HB", _recv_exact(conn, 3))
            payload = _recv_exact(conn, size - 3)
            if ctrl.silent:
                continue
            with send_lock:
                if kind == ord("V"):
                    _send_packet(conn, b"V", b"\x01")
                elif kind == ord("v"):
                    _send_packet(conn, b"v", struct.pack(">IIII", 3, 15, 7, 106331))
                elif kind == ord("O"):
                    frequency = struct.unpack(">d", payload[:8])[0]
                    outputs = [n for n in payload[8:].decode().split(",") if n]
                    output_types = [_type_of(n) for n in outputs]
                    if ctrl.log is not None:
                        print(f"outputs {list(zip(outputs, output_types))}", file=ctrl.log, flush=True)
                    _send_packet(conn, b"O", b"\x01" + ",".join(output_types).encode())
                elif kind == ord("I"):
                    names = [n for n in payload.decode().split(",") if n]
                    recipe = len(inputs) + 1
                    types = [_type_of(n) for n in names]
                    inputs[recipe] = (names, types)
                    _send_packet(conn, b"I", bytes([recipe]) + ",".join(types).encode())
                elif kind == ord("S"):
                    _send_packet(conn, b"S", b"\x01")
                    if not started.is_set():
                        started.set()
                        threading.Thread(target=sender, daemon=True).start()
                elif kind == ord("P"):
                    started.clear()
                    _send_packet(conn, b"P", b"\x01")
                elif kind == ord("U"):
                    recipe = payload[0]
                    if recipe in inputs:
                        names, types = inputs[recipe]
                        offset = 1
                        values = {}
                        for n, t in zip(names, types):
                            fmt = _FORMATS[t]
                            width = struct.calcsize(fmt)
                            values[n] = struct.unpack(fmt, payload[offset:offset + width])[0]
                            offset += width
                        ctrl.command(values)
    except (ConnectionError, OSError, struct.error) as exc:
        if ctrl.log is not None:
            print(f"rtde connection ends: {exc!r}", file=ctrl.log, flush=True)
    finally:
        started.clear()
        try:
            conn.close()
        except OSError:
            pass


def _serve_dashboard(ctrl: FakeController, conn: socket.socket) -> None:
    answers = {
        "polyscopeversion": "URSoftware 3.15.7.106331 (Mar 16 2023)",
        "get serial number": "20185500001",
        "get robot model": "UR5",
        "robotmode": "Robotmode: RUNNING",
        "is in remote control": "true",
        "programstate": "STOPPED <unnamed>",
        "running": "Program running: false",
        "unlock protective stop": "Protective stop releasing",
        "close safety popup": "closing safety popup",
        "power on": "Powering on",
        "brake release": "Brake releasing",
        "stop": "Stopped",
        "safetystatus": "Safetystatus: NORMAL",
    }
    try:
        if not ctrl.silent:
            conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buffer = b""
        while True:
            chunk = conn.recv(1024)
            if not chunk:
                return
            buffer += chunk
            while b"\n" in buffer:
                line, buffer = buffer.split(b"\n", 1)
                text = line.decode(errors="replace").strip()
                if ctrl.silent:
                    continue
                if text.lower() == "unlock protective stop":
                    ctrl.set_safety(1)
                if text.lower() == "safetystatus":
                    bits = ctrl.safety_bits
                    status = "PROTECTIVE_STOP" if bits & 4 else ("ROBOT_EMERGENCY_STOP" if bits & 0xE0 else "NORMAL")
                    conn.sendall(f"Safetystatus: {status}\n".encode())
                    continue
                conn.sendall((answers.get(text.lower(), f"could not understand: '{text}'") + "\n").encode())
    except OSError:
        pass
    finally:
        conn.close()


def _serve_script(ctrl: FakeController, conn: socket.socket) -> None:
    try:
        conn.settimeout(0.3)
        received = b""
        while True:
            try:
                chunk = conn.recv(65536)
            except socket.timeout:
                if received and not ctrl.silent:
                    with ctrl.lock:
                        # The uploaded control script starts: runtime playing, ready for commands.
                        ctrl.program_running = True
                        ctrl.cmd_state = "idle"
                        ctrl.reg_out_int[0] = 1
                    received = b""
                continue
            if not chunk:
                return
            received += chunk
    except OSError:
        pass
    finally:
        conn.close()


def _listen(host: str, port: int, handler, ctrl: FakeController) -> socket.socket:
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind((host, port))
    server.listen(8)

    def accept_loop() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if handler is _serve_rtde:
                with ctrl.lock:
                    ctrl.connections.append(conn)
            threading.Thread(target=handler, args=(ctrl, conn), daemon=True).start()

    threading.Thread(target=accept_loop, daemon=True).start()
    return server


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--silent", action="store_true", help="accept connections, never answer")
    parser.add_argument("--trace", action="store_true", help="print received commands on stderr")
    args = parser.parse_args(argv)
    ctrl = FakeController()
    ctrl.log = sys.stderr if args.trace else None
    ctrl.silent = args.silent
    servers = [
        _listen(args.host, RTDE_PORT, _serve_rtde, ctrl),
        _listen(args.host, DASHBOARD_PORT, _serve_dashboard, ctrl),
        _listen(args.host, SCRIPT_PORT, _serve_script, ctrl),
    ]
    print("READY", flush=True)
    for line in sys.stdin:
        command = line.strip()
        if command == "protective_stop":
            ctrl.set_safety(1 | 4)
        elif command == "emergency_stop":
            ctrl.set_safety(1 | 128)
        elif command == "clear":
            ctrl.set_safety(1)
        elif command == "disconnect":
            with ctrl.lock:
                for conn in ctrl.connections:
                    try:
                        conn.shutdown(socket.SHUT_RDWR)
                        conn.close()
                    except OSError:
                        pass
                ctrl.connections.clear()
        elif command == "disconnect_first":
            with ctrl.lock:
                if ctrl.connections:
                    conn = ctrl.connections.pop(0)
                    try:
                        conn.shutdown(socket.SHUT_RDWR)
                        conn.close()
                    except OSError:
                        pass
        elif command == "silent":
            ctrl.silent = True
        elif command == "freeze":
            ctrl.frozen = True
        elif command == "slow":
            ctrl.speed_factor = 0.1
        elif command == "quit":
            break
        print(f"ACK {command}", flush=True)
    for server in servers:
        server.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())


class FakeURProcess:
    """Run the fake controller in a child process; a context manager that always kills it.

    ``with FakeURProcess() as fake: fake.send("protective_stop")``. The ports are
    fixed, so only one may run at a time (tests using it must not run in parallel).
    """

    def __init__(self, *, silent: bool = False, startup_timeout_s: float = 10.0) -> None:
        self.silent = silent
        self.startup_timeout_s = startup_timeout_s
        self.process = None

    def start(self) -> "FakeURProcess":
        import subprocess

        args = [sys.executable, "-m", "drivers.testing.fake_ur"]
        if self.silent:
            args.append("--silent")
        self.process = subprocess.Popen(
            args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1
        )
        ready = threading.Event()

        def wait_ready() -> None:
            if self.process.stdout.readline().strip() == "READY":
                ready.set()

        threading.Thread(target=wait_ready, daemon=True).start()
        if not ready.wait(self.startup_timeout_s):
            self.stop()
            raise RuntimeError("the fake UR controller did not start (ports 29999/30003/30004 busy?)")
        return self

    def send(self, command: str) -> None:
        """A fault-injection command (see the module docstring); waits for its ACK."""
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        self.process.stdout.readline()

    def stop(self) -> None:
        """Kill the child process (by its own pid) and wait for it."""
        if self.process is None:
            return
        try:
            self.process.kill()
            self.process.wait(timeout=5)
        finally:
            for stream in (self.process.stdin, self.process.stdout):
                try:
                    stream.close()
                except OSError:
                    pass
            self.process = None

    def __enter__(self) -> "FakeURProcess":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
