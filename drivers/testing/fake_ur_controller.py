"""The state and motion of the fake UR controller, shared by its RTDE, dashboard and script servers.

Implements ur_rtde's command handshake through the registers
(``output_int_register_0``: 1 ready, 2 done) and straight-line moves at the
requested speed; see :mod:`fgcd_drivers.testing.fake_ur` for the servers.

The RTDE watchdog is modelled as a real controller runs ur_rtde's control
script: ``setWatchdog(f)`` (command 35, the frequency in
``input_double_register_0``) makes the script call URScript
``rtde_set_watchdog("input_int_register_0", f, "stop")``; when no input package
carrying that register arrives for ``1/f`` s the program is stopped, and with it
the motion; a program stop removes every watchdog (URScript manual,
``rtde_set_watchdog``). ``kickWatchdog()`` only updates the register: ur_rtde
1.6.5 sends it as 0 (seen on this fake's trace), older versions as :data:`KICK`
(their ``WATCHDOG`` type); neither is a command with a handshake. With no watchdog set, a
``moveL`` whose client is gone runs to its end, as on the real arm.
"""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

__all__ = ["FakeController", "KICK", "RTDE_FORMATS", "SET_WATCHDOG", "rtde_type_of"]

#: ur_rtde command ids (``RTDE::RobotCommand::Type``): set the watchdog, and an older version's kick.
SET_WATCHDOG, KICK = 35, 99

_V6 = "VECTOR6D"
_OUTPUT_TYPES = {
    "timestamp": "DOUBLE",
    "target_q": _V6,
    "target_qd": _V6,
    "target_qdd": _V6,
    "target_current": _V6,
    "target_moment": _V6,
    "actual_q": _V6,
    "actual_qd": _V6,
    "actual_current": _V6,
    "joint_control_output": _V6,
    "actual_TCP_pose": _V6,
    "actual_TCP_speed": _V6,
    "actual_TCP_force": _V6,
    "target_TCP_pose": _V6,
    "target_TCP_speed": _V6,
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": _V6,
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": _V6,
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": _V6,
    "script_control_line": "UINT32",
    "ft_raw_wrench": _V6,
    "joint_position_deviation_ratio": _V6,
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "INT32",
    "actual_digital_output_bits_": "UINT64",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "external_force_torque": _V6,
}
RTDE_FORMATS = {
    "DOUBLE": ">d",
    "VECTOR6D": ">6d",
    "VECTOR3D": ">3d",
    "INT32": ">i",
    "UINT32": ">I",
    "UINT64": ">Q",
    "UINT8": ">B",
    "BOOL": ">?",
    "VECTOR6INT32": ">6i",
    "VECTOR6UINT32": ">6I",
}


def rtde_type_of(name: str) -> str:
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
        self.watchdog_period_s: float | None = None  # 1 / min_frequency of rtde_set_watchdog, while set
        self.last_input = time.monotonic()  # the last input package carrying input_int_register_0
        self.watchdog_stops = 0

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

    def stop_program(self) -> None:
        """The dashboard's ``stop``: the motion ends where the arm is, the control script stops.

        A program stop removes every RTDE watchdog (URScript, ``rtde_set_watchdog``).
        """
        self.step()
        with self.lock:
            self.motion = None
            self.speed = np.zeros(6)
            self.program_running = False
            self.reg_out_int[0] = 0
            self.cmd_state = "idle"
            self.done_at = None
            self.watchdog_period_s = None

    def check_watchdog(self) -> bool:
        """Stop the program when its watchdog saw no input update in time (True when it just did)."""
        with self.lock:
            period = self.watchdog_period_s
            if period is None or not self.program_running or time.monotonic() - self.last_input <= period:
                return False
            self.watchdog_stops += 1
        self.stop_program()
        if self.log is not None:
            print(
                f"{time.monotonic() - self.t0:.3f} watchdog: no input for {period:.2f} s, program stopped",
                file=self.log,
                flush=True,
            )
        return True

    # ------------------------------------------------------------------ commands
    def command(self, values: dict[str, float | int]) -> None:
        """A data package of an input recipe: ur_rtde's command protocol."""
        cmd = int(values.get("input_int_register_0", 0))
        if self.log is not None and cmd != KICK:
            print(
                f"{time.monotonic() - self.t0:.3f} cmd {cmd} reg0={self.reg_out_int[0]} {self.cmd_state}",
                file=self.log,
                flush=True,
            )
        with self.lock:
            if "input_int_register_0" in values:
                self.last_input = time.monotonic()  # the watchdog's variable was updated
            if cmd == KICK:
                return  # a continuous command: no handshake, the update is all it does
            if cmd == 0:
                # The client clears the command: the script is ready for the next one.
                if self.program_running and (
                    self.cmd_state == "done" or self.done_at is not None or self.safety_bits & ~1
                ):
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
            elif cmd == SET_WATCHDOG:  # rtde_set_watchdog("input_int_register_0", f, "stop")
                self.watchdog_period_s = 1.0 / d[0] if d[0] > 0 else None
                self.last_input = time.monotonic()
            elif cmd == 29:  # setTcp
                self.T_flange_tcp = _pose_to_T(d[0:6])
            elif cmd == 40:  # getTCPOffset
                self.reg_out_double[0:6] = _T_to_pose(self.T_flange_tcp)
            elif cmd == 58:  # getActualToolFlangePose
                self.reg_out_double[0:6] = _T_to_pose(self.T_base_flange)
            elif cmd == 255:  # stopScript
                self.halt()
                self.watchdog_period_s = None
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
            kind = rtde_type_of(name)
            if kind.startswith("VECTOR6"):
                return [0] * 6
            if kind == "VECTOR3D":
                return [0.0] * 3
            return 0
