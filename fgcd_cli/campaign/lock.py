"""One command at a time on a station: an advisory ``flock`` on ``<campaign>/.locks/<station>.lock``.

Rule: a capture or revisit holds its station's lock from before the rig is
opened until its observation is committed; a second one on the same station
fails at once with one line naming the holder (exit 3) and touches nothing of
the first. The kernel releases a ``flock`` when its holder dies (SIGKILL, power
loss of a local disk), so a lock file left behind by a dead process never blocks:
it is *stale* by construction, and its PID line only serves the message. Local
file systems only (NFS and SMB do not honour ``flock`` reliably; docs/hardware.md,
"Faults").
"""

from __future__ import annotations

import fcntl
import json
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fgcd_cli.campaign.schema import LOCKS_DIR, check_name
from fgcd_cli.errors import CampaignError

__all__ = ["StationBusy", "station_lock"]


class StationBusy(CampaignError):
    """Another fgcd process is capturing or revisiting the station (exit 3)."""


def _holder(fd: int) -> str:
    """``pid N, <command> since HH:MM:SS`` from the lock file, or ``another process`` when unreadable."""
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        info = json.loads(os.read(fd, 4096).decode("utf-8"))
        return f"pid {int(info['pid'])}, {info['command']} since {info['since']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"


@contextmanager
def station_lock(campaign_path: Path, station: str, *, command: str) -> Iterator[Path]:
    """Hold the station's lock for the block (StationBusy at once when another process holds it).

    Parameters
    ----------
    campaign_path : Path
        The campaign directory.
    station : str
        The station's name.
    command : str
        What holds the lock (``relocate``, ``capture``), for the other's message.
    """
    name = check_name(station, "station")
    folder = Path(campaign_path) / LOCKS_DIR
    try:
        folder.mkdir(exist_ok=True)
        fd = os.open(folder / f"{name}.lock", os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        # Rule (README, "Errors"): an operating-system error (a full disk, a read-only campaign folder) is exit 1
        # naming its file, ``Read-only file system: <campaign>/.locks/S.lock``; nothing was opened yet.
        raise OSError(exc.errno, exc.strerror, exc.filename or str(folder / f"{name}.lock")) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _holder(fd)
        os.close(fd)
        raise StationBusy(
            f"station '{name}' is in use by another fgcd ({holder}); wait for it to end, nothing was opened or written"
        ) from None
    try:
        info = {"pid": os.getpid(), "command": command, "since": time.strftime("%H:%M:%S")}
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(info).encode("utf-8"), 0)
        except OSError:
            pass  # a full disk: the lock holds all the same, only the other's message is vaguer
        yield folder / f"{name}.lock"
    finally:
        os.close(fd)  # releases the flock
