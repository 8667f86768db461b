"""Pre-flight of a UR controller in pure Python, before ``ur_rtde`` touches it.

The ``ur_rtde`` interface constructors have no timeout and hold the GIL: a peer
that accepts TCP but never answers, or answers the protocol request but never
streams its state, would freeze the interpreter (``docs/hardware.md``,
"Universal Robots arm"). Written by hand because no library speaks RTDE with
timeouts; only the handful of RTDE v2 packets the check needs are here.
"""

from __future__ import annotations

import socket
import struct

from fgcd_core.platform import PlatformConnectionError, PlatformTimeout

__all__ = ["preflight"]


def preflight(host: str, *, port: int = 30004, dashboard_port: int = 29999, timeout_s: float = 2.0) -> str:
    """Check that a UR controller answers before ``ur_rtde`` touches it.

    Opens RTDE with a timeout, sends the protocol-version request (v2) and
    requires an answer; then reads the dashboard greeting.

    Returns
    -------
    str
        The dashboard greeting.

    Raises
    ------
    PlatformConnectionError
        Refused or unreachable.
    PlatformTimeout
        The peer accepted the connection but did not answer in time.
    """
    try:
        with _connect(host, port, timeout_s) as sock:
            sock.settimeout(timeout_s)
            sock.sendall(struct.pack(">HBH", 5, ord("V"), 2))
            header = _recv_exact(sock, 3)
            size, kind = struct.unpack(">HB", header)
            if kind != ord("V") or not 4 <= size <= 64:  # garbage: do not wait for a bogus length
                raise PlatformConnectionError(f"{host}:{port} does not speak RTDE (unexpected answer {header!r})")
            body = _recv_exact(sock, size - 3)
            if not body or body[0] != 1:
                raise PlatformConnectionError(f"{host}:{port} does not speak RTDE protocol version 2")
            _require_state_stream(sock, host)
        with _connect(host, dashboard_port, timeout_s) as sock:
            sock.settimeout(timeout_s)
            greeting = sock.recv(256).decode(errors="replace").strip()
            if "Dashboard" not in greeting:
                raise PlatformConnectionError(f"{host}:{dashboard_port} is not a UR dashboard server")
            return greeting
    except TimeoutError:
        raise PlatformTimeout(
            f"the UR controller at {host} accepted the connection but did not answer within {timeout_s:.1f} s"
        ) from None
    except (ConnectionError, OSError) as exc:
        raise PlatformConnectionError(f"cannot reach the UR controller at {host}: {exc}") from None


def _connect(host: str, port: int, timeout_s: float) -> socket.socket:
    """A TCP connection; a connect that times out is a network that carries nothing (cable, switch, power).

    Rule: "accepted the connection but did not answer" is said only of a peer that accepted
    (docs/hardware.md, faults: a pulled cable and a hung controller need different actions).
    """
    try:
        return socket.create_connection((host, port), timeout=timeout_s)
    except TimeoutError:
        raise PlatformConnectionError(
            f"no answer from the UR controller at {host}:{port} within {timeout_s:.1f} s: nothing reaches it "
            "(network cable, switch, or the controller is off)"
        ) from None


def _rtde_packet(sock: socket.socket, kind: str) -> bytes:
    """The body of the next RTDE packet of ``kind`` (others, such as text messages, are skipped)."""
    while True:
        size, got = struct.unpack(">HB", _recv_exact(sock, 3))
        body = _recv_exact(sock, size - 3)
        if got == ord(kind):
            return body


def _require_state_stream(sock: socket.socket, host: str) -> None:
    """Ask for the controller's timestamp and require one state package (RTDE v2:
    CONTROL_PACKAGE_SETUP_OUTPUTS, CONTROL_PACKAGE_START, DATA_PACKAGE, then PAUSE).

    A controller that answers the protocol request but does not stream would hang the
    receive interface's constructor, which waits for the first package with no timeout and
    the GIL held (module docstring). The socket's timeout bounds every wait here.
    """
    sock.sendall(struct.pack(">HB", 3 + 8 + len(b"timestamp"), ord("O")) + struct.pack(">d", 10.0) + b"timestamp")
    recipe = _rtde_packet(sock, "O")
    if not recipe or b"NOT_FOUND" in recipe:
        raise PlatformConnectionError(f"the UR controller at {host} refused an RTDE output recipe")
    sock.sendall(struct.pack(">HB", 3, ord("S")))
    if _rtde_packet(sock, "S")[:1] != b"\x01":
        raise PlatformConnectionError(f"the UR controller at {host} refused to start RTDE streaming")
    try:
        _rtde_packet(sock, "U")
    except TimeoutError:
        raise PlatformTimeout(
            f"the UR controller at {host} answers but sends no state (it may be hung); "
            "check the controller before moving"
        ) from None
    sock.sendall(struct.pack(">HB", 3, ord("P")))


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError("connection closed by the controller")
        data += chunk
    return data
