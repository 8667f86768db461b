"""A fake Universal Robots controller for the real ``ur_rtde`` client, run as its own process.

``python -m fgcd_drivers.testing.fake_ur [--host 127.0.0.1] [--silent]`` listens on the
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
``state``            answers ``ACK state moving=0|1 safety=BITS program=0|1 watchdog_stops=N``: the arm's
                     own motion (it progresses even while frozen: a hung stream does not stop an arm)
``quit``             exit

A watchdog set by the client (``setWatchdog``) stops the program, and the
motion, when its input updates stop arriving (see
:mod:`fgcd_drivers.testing.fake_ur_controller`); the controller checks it every
10 ms, whatever the state of the network.

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
import socket
import struct
import sys
import threading
import time

from fgcd_drivers.testing.fake_ur_controller import RTDE_FORMATS, FakeController, rtde_type_of

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003


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
    fmt = RTDE_FORMATS[kind]
    if kind.startswith("VECTOR"):
        return struct.pack(fmt, *value)
    if kind in ("DOUBLE",):
        return struct.pack(fmt, float(value))
    return struct.pack(fmt, int(value))


class _RtdeSession:
    """One RTDE connection: recipes, the data-package sender thread and the client's packets."""

    def __init__(self, ctrl: FakeController, conn: socket.socket) -> None:
        self.ctrl = ctrl
        self.conn = conn
        self.outputs: list[str] = []
        self.output_types: list[str] = []
        self.inputs: dict[int, tuple[list[str], list[str]]] = {}
        self.frequency = 125.0
        self.started = threading.Event()
        self.send_lock = threading.Lock()
        self._last_logged = None

    def sender(self) -> None:
        """Send data packages at the recipe's frequency (at most 125 Hz) until paused."""
        ctrl = self.ctrl
        period = 1.0 / min(self.frequency, 125.0)
        while self.started.is_set():
            if ctrl.frozen:
                time.sleep(period)
                continue
            ctrl.step()
            try:
                payload = b"\x01" + b"".join(_pack(t, ctrl.outputs(n)) for n, t in zip(self.outputs, self.output_types))
            except Exception as exc:  # noqa: BLE001 - a fake must say why it stopped
                print(f"fake_ur sender failed: {exc!r}", file=sys.stderr, flush=True)
                raise
            self._trace_registers()
            try:
                with self.send_lock:
                    _send_packet(self.conn, b"U", payload)
            except OSError:
                return
            time.sleep(period)

    def _trace_registers(self) -> None:
        ctrl = self.ctrl
        if ctrl.log is not None and "output_int_register_0" in self.outputs:
            state = (ctrl.reg_out_int[0], round(ctrl.reg_out_double[0], 3))
            if state != self._last_logged:
                self._last_logged = state
                print(f"{time.monotonic() - ctrl.t0:.3f} sent reg0={state[0]} d0={state[1]}", file=ctrl.log, flush=True)

    def handle(self, kind: int, payload: bytes) -> None:
        """Answer one client packet (caller holds ``send_lock``)."""
        conn, ctrl = self.conn, self.ctrl
        if kind == ord("V"):
            _send_packet(conn, b"V", b"\x01")
        elif kind == ord("v"):
            _send_packet(conn, b"v", struct.pack(">IIII", 3, 15, 7, 106331))
        elif kind == ord("O"):
            self.frequency = struct.unpack(">d", payload[:8])[0]
            self.outputs = [n for n in payload[8:].decode().split(",") if n]
            self.output_types = [rtde_type_of(n) for n in self.outputs]
            if ctrl.log is not None:
                print(f"outputs {list(zip(self.outputs, self.output_types))}", file=ctrl.log, flush=True)
            _send_packet(conn, b"O", b"\x01" + ",".join(self.output_types).encode())
        elif kind == ord("I"):
            names = [n for n in payload.decode().split(",") if n]
            recipe = len(self.inputs) + 1
            types = [rtde_type_of(n) for n in names]
            self.inputs[recipe] = (names, types)
            _send_packet(conn, b"I", bytes([recipe]) + ",".join(types).encode())
        elif kind == ord("S"):
            _send_packet(conn, b"S", b"\x01")
            if not self.started.is_set():
                self.started.set()
                threading.Thread(target=self.sender, daemon=True).start()
        elif kind == ord("P"):
            self.started.clear()
            _send_packet(conn, b"P", b"\x01")
        elif kind == ord("U"):
            self._data_package(payload)

    def _data_package(self, payload: bytes) -> None:
        recipe = payload[0]
        if recipe not in self.inputs:
            return
        names, types = self.inputs[recipe]
        offset = 1
        values = {}
        for n, t in zip(names, types):
            fmt = RTDE_FORMATS[t]
            width = struct.calcsize(fmt)
            values[n] = struct.unpack(fmt, payload[offset : offset + width])[0]
            offset += width
        self.ctrl.command(values)


def _serve_rtde(ctrl: FakeController, conn: socket.socket) -> None:
    session = _RtdeSession(ctrl, conn)
    try:
        while True:
            size, kind = struct.unpack(">HB", _recv_exact(conn, 3))
            payload = _recv_exact(conn, size - 3)
            if ctrl.silent:
                continue
            with session.send_lock:
                session.handle(kind, payload)
    except (ConnectionError, OSError, struct.error) as exc:
        if ctrl.log is not None:
            print(f"rtde connection ends: {exc!r}", file=ctrl.log, flush=True)
    finally:
        session.started.clear()
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
                if text.lower() == "stop":
                    ctrl.stop_program()
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
            except TimeoutError:
                if received and not ctrl.silent:
                    with ctrl.lock:
                        # The uploaded control script starts: runtime playing, ready for commands.
                        ctrl.program_running = True
                        ctrl.watchdog_period_s = None  # a new program has no watchdog yet
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

    def watchdog_loop() -> None:
        while True:
            time.sleep(0.01)
            ctrl.check_watchdog()

    threading.Thread(target=watchdog_loop, name="fake-ur-watchdog", daemon=True).start()
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
        elif command == "state":  # for fault campaigns: is the arm moving, its safety bits, its program
            ctrl.step()  # the motion is the arm's: it goes on while the stream is frozen
            with ctrl.lock:
                moving = int(ctrl.motion is not None)
                print(
                    f"ACK state moving={moving} safety={ctrl.safety_bits} program={int(ctrl.program_running)} "
                    f"watchdog_stops={ctrl.watchdog_stops}",
                    flush=True,
                )
            continue
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

    def __init__(
        self,
        *,
        silent: bool = False,
        startup_timeout_s: float = 10.0,
        host: str = "127.0.0.1",
        prefix: list[str] | None = None,
    ) -> None:
        self.silent = silent
        self.startup_timeout_s = startup_timeout_s
        self.host = host
        self.prefix = list(prefix or [])  # e.g. ``ip netns exec NS`` (fgcd_drivers.testing.link_cut)
        self.process = None

    def start(self) -> FakeURProcess:
        import subprocess

        args = [*self.prefix, sys.executable, "-m", "fgcd_drivers.testing.fake_ur", "--host", self.host]
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
            exited = self.process.poll() is not None
            self.stop()
            if exited:  # its bind failed: another controller (a fake of another test run) holds the ports
                raise RuntimeError(
                    f"the fake UR controller did not start: ports 29999/30003/30004 on {self.host} "
                    "are busy (another fake UR running?)"
                )
            raise RuntimeError(f"the fake UR controller printed no READY within {self.startup_timeout_s:.0f} s")
        return self

    def send(self, command: str) -> None:
        """A fault-injection command (see the module docstring); waits for its ACK."""
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        self.process.stdout.readline()

    def state(self) -> dict[str, int]:
        """``{"moving": 0|1, "safety": bits}``: the fake arm's own motion and safety state."""
        self.process.stdin.write("state\n")
        self.process.stdin.flush()
        words = self.process.stdout.readline().split()[2:]
        return {k: int(v) for k, v in (w.split("=") for w in words)}

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

    def __enter__(self) -> FakeURProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
