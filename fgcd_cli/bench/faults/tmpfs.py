"""Small real file systems for ``fgcd bench faults``: a size-limited ``tmpfs``, filled, or remounted read-only.

The real-file-system faults (:mod:`fgcd_cli.bench.faults.real_fs`) need root and a
kernel that lets it mount a ``tmpfs``. Where that is not allowed (not root, a
container without ``CAP_SYS_ADMIN``, no ``mount``), :func:`small_fs` raises
:class:`MountUnavailable` with one line saying why, and the faults report
themselves skipped (never passed). Every mount is undone in a ``finally``: a
plain ``umount``, else a lazy one (``umount -l``, a child still holding a file).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["MountUnavailable", "fill_to", "free_bytes", "mount_refusal", "remount_readonly", "small_fs", "tree_bytes"]

#: Bytes the filler writes per call (the last write is cut to the byte count that stays free).
CHUNK = 1 << 20


class MountUnavailable(RuntimeError):
    """A tmpfs cannot be mounted here (not root, or ``mount`` refused): the fault is skipped, saying why."""


def mount_refusal() -> str | None:
    """Why a tmpfs cannot be mounted here, or None when it can be tried (root and a ``mount`` command)."""
    if os.geteuid() != 0:
        return "not root: mounting a size-limited tmpfs needs root (run the real-file-system faults as root)"
    if shutil.which("mount") is None or shutil.which("umount") is None:
        return "no mount/umount command on this system"
    return None


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(args, capture_output=True, text=True, check=False, timeout=60)


@contextmanager
def small_fs(size_bytes: int, *, parent: Path | None = None) -> Iterator[Path]:
    """A fresh tmpfs of ``size_bytes`` mounted on a new folder under ``parent``; unmounted and removed after.

    Raises
    ------
    MountUnavailable
        Not root, or ``mount -t tmpfs`` failed (its message is kept).
    """
    refusal = mount_refusal()
    if refusal is not None:
        raise MountUnavailable(refusal)
    point = Path(tempfile.mkdtemp(prefix="fgcd-smallfs-", dir=None if parent is None else str(parent)))
    done = _run(["mount", "-t", "tmpfs", "-o", f"size={int(size_bytes)},mode=0755", "tmpfs", str(point)])
    if done.returncode != 0:
        point.rmdir()
        raise MountUnavailable(f"mount -t tmpfs refused: {(done.stderr or done.stdout).strip() or done.returncode}")
    try:
        yield point
    finally:
        _unmount(point)


def _unmount(point: Path) -> None:
    """Unmount ``point`` (lazily when still busy) and remove the folder."""
    if _run(["umount", str(point)]).returncode != 0:
        _run(["umount", "-l", str(point)])
    try:
        point.rmdir()
    except OSError:
        pass


def remount_readonly(point: Path) -> None:
    """Remount the tmpfs at ``point`` read-only (root ignores permission bits: chmod would not stop it)."""
    done = _run(["mount", "-o", "remount,ro", str(point)])
    if done.returncode != 0:
        raise MountUnavailable(f"remount,ro refused: {(done.stderr or done.stdout).strip() or done.returncode}")


def free_bytes(path: Path) -> int:
    """Bytes an unprivileged writer may still write on the file system of ``path`` (``statvfs``)."""
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


def tree_bytes(path: Path) -> int:
    """Total size of the files under ``path``."""
    return sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file() and not p.is_symlink())


def fill_to(point: Path, leave_bytes: int) -> int:
    """Fill the file system of ``point`` with ``point/.filler`` until about ``leave_bytes`` stay free; the free bytes.

    A tmpfs counts whole pages: what stays free is ``leave_bytes`` rounded down to a page (0 when asked for less).
    """
    filler = Path(point) / ".filler"
    with open(filler, "ab", buffering=0) as fh:
        while True:
            excess = free_bytes(point) - int(leave_bytes)
            if excess <= 0:
                break
            try:
                fh.write(b"\0" * min(CHUNK, excess))
            except OSError:
                break  # full already: nothing stays free
    return free_bytes(point)
