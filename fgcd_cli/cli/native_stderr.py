"""Native libraries' own stderr lines (ur_rtde's reconnect chatter, libpng warnings) go to a log, not the terminal.

Rule (README, "Errors"): a failing command prints one line on stderr. C and
C++ libraries write straight to file descriptor 2, past Python; the console
entry point therefore points descriptor 2 at ``native-stderr.log`` in fgcd's
state folder (``$XDG_STATE_HOME/fgcd``, else ``~/.local/state/fgcd``) and keeps
Python's ``sys.stderr`` on the original terminal or pipe. The log is appended
to and names the process of each run.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

__all__ = ["native_stderr_log", "route_native_stderr"]


def native_stderr_log() -> Path:
    """Where native libraries' stderr lines go."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "fgcd" / "native-stderr.log"


def route_native_stderr() -> Path | None:
    """Point descriptor 2 at the log, ``sys.stderr`` at a copy of the former descriptor 2; the log, or None.

    Nothing changes when the log cannot be opened (a read-only home): native
    lines then reach the terminal as before.
    """
    path = native_stderr_log()
    if _descriptor_is(2, path):
        return path  # already routed (the entry point called twice in one process): a second dup would lose sys.stderr
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        log = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        os.write(
            log, f"--- fgcd pid {os.getpid()} {time.strftime('%Y-%m-%dT%H:%M:%S')} {' '.join(sys.argv[1:3])}\n".encode()
        )
        terminal = os.dup(2)
    except OSError:
        return None
    sys.stderr.flush()
    sys.stderr = os.fdopen(
        terminal, "w", buffering=1, encoding=sys.stderr.encoding or "utf-8", errors="backslashreplace"
    )
    os.dup2(log, 2)
    os.close(log)
    return path


def _descriptor_is(fd: int, path: Path) -> bool:
    """True when descriptor ``fd`` is open on the file ``path``."""
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)
