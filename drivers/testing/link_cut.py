"""A network link to a test controller that can be cut from outside, as a pulled cable cuts it.

:class:`NetnsLink` puts the controller in its own Linux network namespace joined
to this one by a veth pair (``ip netns``, ``ip link``; needs root or
``CAP_NET_ADMIN``). :meth:`NetnsLink.cut` sets the namespace's end of the pair
down: packets then vanish in both directions with no RST and no ICMP, so the
client's sockets stay open and its sends succeed into the kernel's buffer, as
when a cable is pulled between two switches; new connections get no answer.
:meth:`NetnsLink.restore` sets it up again. Each namespace has its own ports,
so a fake UR controller inside one does not collide with one on ``127.0.0.1``.

Where namespaces are not permitted (no ``ip``, not root, a container without
``CAP_NET_ADMIN``), :class:`ProxyLink` is the fallback: a TCP proxy thread on
``127.0.0.2`` forwards the controller's ports to ``127.0.0.3`` (clear of a fake
controller on ``127.0.0.1``); its
:meth:`ProxyLink.cut` stops forwarding both ways and answers no new connection
(the sockets stay open, no RST), so the dashboard is unreachable too.

:func:`open_link` returns whichever works, and ``link.kind`` says which. Run the
controller on ``link.fake_host`` with ``link.prefix()`` before its command;
the client connects to ``link.address``.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import threading
from pathlib import Path

__all__ = ["LinkUnavailable", "NetnsLink", "ProxyLink", "netns_problem", "open_link"]


class LinkUnavailable(RuntimeError):
    """Neither a namespace nor a proxy could be set up (the reason is the message)."""


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=20, check=check)


def netns_problem() -> str | None:
    """Why a network namespace cannot be made here, or None when it can."""
    if shutil.which("ip") is None:
        return "the 'ip' tool (iproute2) is not installed"
    if os.geteuid() != 0:
        return "network namespaces need root (or CAP_NET_ADMIN)"
    return None


class NetnsLink:
    """A namespace ``fgcd-link-<pid>-<n>`` with a veth pair: this side ``host_ip``, the namespace ``ns_ip``.

    Use as a context manager; :meth:`close` always removes the namespace and the pair.
    """

    kind = "netns"
    _count = 0

    def __init__(self) -> None:
        NetnsLink._count += 1
        tag = f"{os.getpid() % 100000}{NetnsLink._count % 100}"
        self.name = f"fgcd-link-{tag}"
        self.host_dev, self.ns_dev = f"fgl{tag}h", f"fgl{tag}n"
        subnet = (os.getpid() * 7 + NetnsLink._count) % 250 + 1
        self.host_ip, self.ns_ip = f"10.213.{subnet}.1", f"10.213.{subnet}.2"
        self.address = self.fake_host = self.ns_ip  # where the client connects, and the controller listens
        self._made = False

    def open(self) -> NetnsLink:
        """Create the namespace, the veth pair and their addresses; LinkUnavailable when not permitted."""
        problem = netns_problem()
        if problem is not None:
            raise LinkUnavailable(problem)
        try:
            _ip("netns", "add", self.name)
            self._made = True
            _ip("link", "add", self.host_dev, "type", "veth", "peer", "name", self.ns_dev)
            _ip("link", "set", self.ns_dev, "netns", self.name)
            _ip("addr", "add", f"{self.host_ip}/30", "dev", self.host_dev)
            _ip("link", "set", self.host_dev, "up")
            self._in_ns("ip", "addr", "add", f"{self.ns_ip}/30", "dev", self.ns_dev)
            self._in_ns("ip", "link", "set", self.ns_dev, "up")
            self._in_ns("ip", "link", "set", "lo", "up")
        except (subprocess.CalledProcessError, OSError, subprocess.TimeoutExpired) as exc:
            detail = getattr(exc, "stderr", "") or str(exc)
            self.close()
            raise LinkUnavailable(f"cannot make a network namespace: {detail.strip()}") from None
        return self

    def _in_ns(self, *args: str) -> None:
        subprocess.run(
            ["ip", "netns", "exec", self.name, *args], capture_output=True, text=True, timeout=20, check=True
        )

    def prefix(self) -> list[str]:
        """The command prefix that runs a program inside the namespace."""
        return ["ip", "netns", "exec", self.name]

    def cut(self) -> None:
        """The cable is pulled: the namespace's end goes down, packets vanish silently."""
        self._in_ns("ip", "link", "set", self.ns_dev, "down")

    def restore(self, *, timeout_s: float = 5.0) -> None:
        """The cable is back: the namespace's end up, and this end's carrier with it.

        Rule: the link counts as back once the host end reports ``operstate`` up (carrier on
        both ends) and the neighbour entry the cut left failed is flushed; a connect made before
        that gets ``No route to host``, as a connect made while a real cable is still negotiating.
        """
        import time

        self._in_ns("ip", "link", "set", self.ns_dev, "up")
        state = Path("/sys/class/net") / self.host_dev / "operstate"
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and state.read_text().strip() != "up":
            time.sleep(0.02)
        _ip("neigh", "flush", "to", self.ns_ip, "dev", self.host_dev, check=False)

    def close(self) -> None:
        """Remove the veth pair and the namespace (idempotent; processes inside must be ended first)."""
        if not self._made:
            return
        _ip("link", "del", self.host_dev, check=False)
        _ip("netns", "del", self.name, check=False)
        self._made = False

    def __enter__(self) -> NetnsLink:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()


class ProxyLink:
    """TCP forwarding of ``ports`` from ``127.0.0.2`` to ``target``, cut on demand (the fallback)."""

    kind = "proxy"

    def __init__(self, ports: tuple[int, ...] = (29999, 30003, 30004), target: str = "127.0.0.3") -> None:
        self.ports, self.target = ports, target
        self.address, self.fake_host = "127.0.0.2", target
        self._cut = threading.Event()
        self._closed = threading.Event()
        self._servers: list[socket.socket] = []
        self._conns: list[socket.socket] = []
        self._lock = threading.Lock()

    def open(self) -> ProxyLink:
        """Listen on every port; LinkUnavailable when an address is busy."""
        try:
            for port in self.ports:
                server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                server.bind((self.address, port))
                server.listen(8)
                server.settimeout(0.1)
                self._servers.append(server)
                threading.Thread(target=self._accept, args=(server, port), daemon=True).start()
        except OSError as exc:
            self.close()
            raise LinkUnavailable(f"cannot listen on {self.address}: {exc}") from None
        return self

    def prefix(self) -> list[str]:
        """No prefix: the controller runs in this namespace, on ``target``."""
        return []

    def _accept(self, server: socket.socket, port: int) -> None:
        while not self._closed.is_set():
            try:
                client, _ = server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            if self._cut.is_set():  # no answer: held open, never forwarded
                with self._lock:
                    self._conns.append(client)
                continue
            try:
                upstream = socket.create_connection((self.target, port), timeout=2.0)
            except OSError:
                client.close()
                continue
            with self._lock:
                self._conns += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pump, args=(a, b), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        src.settimeout(0.05)
        while not self._closed.is_set():
            if self._cut.is_set():  # the bytes vanish: neither read nor written, the sockets stay open
                self._closed.wait(0.05)
                continue
            try:
                data = src.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                data = b""
            if not data:
                for s in (src, dst):
                    try:
                        s.shutdown(socket.SHUT_RDWR)
                    except OSError:
                        pass
                return
            if self._cut.is_set():
                continue  # read just as the cable went: these bytes are lost too
            try:
                dst.sendall(data)
            except OSError:
                return

    def cut(self) -> None:
        """Stop forwarding in both directions and answer no new connection."""
        self._cut.set()

    def restore(self) -> None:
        """Forward again (the connections opened during the cut stay unanswered, as their SYNs were lost)."""
        self._cut.clear()

    def close(self) -> None:
        """Close every socket."""
        self._closed.set()
        with self._lock:
            for s in self._servers + self._conns:
                try:
                    s.close()
                except OSError:
                    pass
            self._servers, self._conns = [], []

    def __enter__(self) -> ProxyLink:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()


def open_link(*, prefer: str = "netns"):
    """A cuttable link, opened: :class:`NetnsLink` when namespaces work (unless ``prefer="proxy"``), else
    :class:`ProxyLink`.

    Raises
    ------
    LinkUnavailable
        Neither works here (the message says why).
    """
    reasons = []
    if prefer == "netns":
        try:
            return NetnsLink().open()
        except LinkUnavailable as exc:
            reasons.append(str(exc))
    try:
        return ProxyLink().open()
    except LinkUnavailable as exc:
        reasons.append(str(exc))
    raise LinkUnavailable("; ".join(reasons))
