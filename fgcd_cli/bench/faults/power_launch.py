"""``python -m fgcd_cli.bench.faults.power_launch ARGS``: ``fgcd ARGS`` that loses power at a chosen instant of its writing.

Fault injection for ``fgcd bench faults`` only (the power-loss group,
:mod:`fgcd_cli.bench.faults.power`). A Python audit hook sees every file-system
operation the process makes (``open`` for writing, ``os.rename`` — which
``os.replace`` raises too —, ``os.remove``, ``os.mkdir``, ``os.rmdir``,
``os.chmod``, ``shutil.*``); those on paths under ``FGCD_BENCH_POWER_UNDER``
are *write events*, numbered from 1 from the first one whose path contains
``FGCD_BENCH_POWER_FROM`` (empty: from the first one), and only those whose path
contains ``FGCD_BENCH_POWER_ONLY`` and, when ``FGCD_BENCH_POWER_EVENT`` is set, only
audit events of that name (``os.remove``: the journal's removal). The process kills itself
with SIGKILL, as a power cut stops it (no handler, no ``finally``, no flush):

* before the ``FGCD_BENCH_POWER_AT``-th event (so events ``1 .. N-1`` are done
  and the N-th is not), or
* ``FGCD_BENCH_POWER_DELAY_S`` seconds after the first event, from a thread:
  the instants inside one operation (the bytes of an image being written), which
  raise no event of their own.

Neither set: a counting run, killed never. ``FGCD_BENCH_POWER_LOG`` (a path
outside the campaign) receives one line per event, ``<n> <seconds> <event>
<path>``, and ``kill <n> <seconds> <how>`` just before the kill; it is written
with ``os.write`` on a descriptor opened before the hook, which raises no event.
``FGCD_BENCH_POWER_TARGET`` runs another module, or a ``.py`` file, instead of
the fgcd CLI (the launcher's own tests).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["LoggedEvent", "PowerPlan", "install_power_loss", "read_log", "write_event_path"]

#: Audit events that change the file system (``open`` only with a writing flag).
WRITE_EVENTS = frozenset(
    {
        "open",
        "os.rename",
        "os.remove",
        "os.mkdir",
        "os.rmdir",
        "os.chmod",
        "os.truncate",
        "os.link",
        "os.symlink",
        "shutil.rmtree",
        "shutil.move",
        "shutil.copyfile",
        "shutil.copytree",
        "shutil.copymode",
        "shutil.copystat",
    }
)
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND
#: The audit argument that holds a relative path's ``dir_fd`` (``shutil.rmtree`` works through descriptors).
_DIR_FD_ARG = {"os.remove": 1, "os.rmdir": 1, "os.mkdir": 2, "os.chmod": 2, "os.rename": 2}


@dataclass(frozen=True, kw_only=True)
class PowerPlan:
    """When the launched process loses power.

    Attributes
    ----------
    under : str
        Only operations on paths below this folder are events (the campaign's ``stations/``).
    start : str
        Events count from the first one whose path contains this (empty: the first one).
    only : str
        Only events whose path contains this count (empty: every one).
    event : str
        Only audit events of this name count (empty: every write event).
    kill_at : int or None
        SIGKILL before this event (1-based); None: not by count.
    delay_s : float or None
        SIGKILL this long after the first event; None: not by time.
    log : str or None
        The event log's path.
    """

    under: str
    start: str = ""
    only: str = ""
    event: str = ""
    kill_at: int | None = None
    delay_s: float | None = None
    log: str | None = None

    @classmethod
    def from_env(cls, env: dict | None = None) -> PowerPlan:
        """The plan of the ``FGCD_BENCH_POWER_*`` variables."""
        env = os.environ if env is None else env
        at, delay = env.get("FGCD_BENCH_POWER_AT", ""), env.get("FGCD_BENCH_POWER_DELAY_S", "")
        return cls(
            under=env["FGCD_BENCH_POWER_UNDER"],
            start=env.get("FGCD_BENCH_POWER_FROM", ""),
            only=env.get("FGCD_BENCH_POWER_ONLY", ""),
            event=env.get("FGCD_BENCH_POWER_EVENT", ""),
            kill_at=int(at) if at else None,
            delay_s=float(delay) if delay else None,
            log=env.get("FGCD_BENCH_POWER_LOG") or None,
        )


@dataclass(frozen=True)
class LoggedEvent:
    """One line of the event log: the event's number, seconds since the first, name and path (``kill``: how)."""

    n: int
    seconds: float
    event: str
    path: str


def write_event_path(event: str, args: tuple) -> str | None:
    """The absolute path a file-system-changing audit event acts on (the source of a rename); None for others."""
    if event not in WRITE_EVENTS or not args:
        return None
    if event == "open":
        flags = args[2] if len(args) > 2 and isinstance(args[2], int) else 0
        mode = args[1] if len(args) > 1 and isinstance(args[1], str) else ""
        if not (flags & _WRITE_FLAGS or any(c in mode for c in "wax+")):
            return None
    path = args[0]
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        return None  # an open descriptor: its file was counted when it was opened
    path = os.fspath(path)
    if not os.path.isabs(path):
        index = _DIR_FD_ARG.get(event)
        dir_fd = args[index] if index is not None and len(args) > index else None
        base = os.getcwd()
        if isinstance(dir_fd, int) and dir_fd >= 0:
            try:
                base = os.readlink(f"/proc/self/fd/{dir_fd}")
            except OSError:
                return None
        path = os.path.join(base, path)
    return os.path.normpath(path)


class _PowerCut:
    """The audit hook's state: events seen, the log, the pending kill."""

    def __init__(self, plan: PowerPlan) -> None:
        self.plan = plan
        self.root = os.path.realpath(plan.under) + os.sep
        self.lock = threading.Lock()
        self.count = 0
        self.started: float | None = None
        self.fd = os.open(plan.log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644) if plan.log else None

    def _log(self, text: str) -> None:
        if self.fd is not None:
            os.write(self.fd, (text + "\n").encode("utf-8", errors="replace"))

    def kill(self, how: str) -> None:
        """Log the instant, then SIGKILL this process (nothing after it runs)."""
        self._log(f"kill {self.count} {time.monotonic() - (self.started or time.monotonic()):.4f} {how}")
        os.kill(os.getpid(), signal.SIGKILL)

    def _timer(self) -> None:
        time.sleep(self.plan.delay_s)
        with self.lock:
            self.kill(f"after {self.plan.delay_s:.3f} s")

    def hook(self, event: str, args: tuple) -> None:
        """The audit hook: count the write events under the root, kill at the planned one."""
        if event not in WRITE_EVENTS or (self.plan.event and event != self.plan.event):
            return
        path = write_event_path(event, args)
        if path is None or not (path + os.sep).startswith(self.root) or self.plan.only not in path:
            return
        with self.lock:
            if self.started is None:
                if self.plan.start and self.plan.start not in path:
                    return
                self.started = time.monotonic()
                if self.plan.delay_s is not None:
                    threading.Thread(target=self._timer, name="power-cut", daemon=True).start()
            self.count += 1
            if self.plan.kill_at is not None and self.count >= self.plan.kill_at:
                self.kill(f"before {event} {path}")
            self._log(f"{self.count} {time.monotonic() - self.started:.4f} {event} {path}")


def install_power_loss(plan: PowerPlan) -> None:
    """Install the audit hook of ``plan`` in this process (for good: audit hooks cannot be removed)."""
    sys.addaudithook(_PowerCut(plan).hook)


def read_log(path: Path) -> tuple[list[LoggedEvent], LoggedEvent | None]:
    """``(events, kill)`` of an event log (``kill`` None: the process was not killed by the plan)."""
    events, kill = [], None
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return [], None
    for line in text.splitlines():
        kind, _, rest = line.partition(" ") if line.startswith("kill ") else ("", "", line)
        fields = rest.split(" ", 3)
        try:
            if kind == "kill":
                kill = LoggedEvent(int(fields[0]), float(fields[1]), "kill", " ".join(fields[2:]))
            else:
                events.append(LoggedEvent(int(fields[0]), float(fields[1]), fields[2], fields[3]))
        except (ValueError, IndexError):
            continue  # a line the kill cut short
    return events, kill


def _main() -> None:
    import runpy

    install_power_loss(PowerPlan.from_env())
    target = os.environ.get("FGCD_BENCH_POWER_TARGET", "fgcd_cli.cli.app")
    if target.endswith(".py"):
        sys.argv[0] = target
        runpy.run_path(target, run_name="__main__")
    else:
        runpy.run_module(target, run_name="__main__", alter_sys=True)  # the fgcd command itself


if __name__ == "__main__":
    _main()
