"""What ``fgcd bench soak`` measures after each revisit: the process's resources and their growth.

One :class:`ResourceSample` per revisit, read from ``/proc/self`` (Linux): the
resident set (``VmRSS``) and its peak (``VmHWM``), every thread of the process
(``/proc/self/task``: the native ones of OpenCV, BLAS and the VSE included) beside
:func:`threading.active_count` (Python's), the open file descriptors
(``/proc/self/fd``), the objects Python's collector tracks (a leak of Python
objects grows it; the allocator's fragmentation, which also grows the resident
set, does not) and the temporary files a revisit left: new entries in
:func:`tempfile.gettempdir` and the store's ``.tmp-*`` under the campaign
(:data:`fgcd_cli.campaign.atomic.TMP_PREFIX`). Growth per revisit is the slope
of a least-squares line (:func:`growth_per_revisit`), after a warm-up: the first
revisits load the libraries, build the simulator's caches and fill malloc's
arenas, which is not a leak (docs/benchmarks.md, "Soak (`fgcd bench soak`)").
"""

from __future__ import annotations

import gc
import os
import tempfile
import threading
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from fgcd_cli.campaign.atomic import TMP_PREFIX

__all__ = [
    "ResourceSample",
    "TempBaseline",
    "growth_per_revisit",
    "proc_status_mb",
    "sample_resources",
    "summarize_samples",
]


@dataclass(frozen=True, kw_only=True)
class ResourceSample:
    """The process after one revisit (or after the set-up: ``index`` 0).

    Attributes
    ----------
    index : int
        Revisit number, from 1 (0: after the reference capture, before any revisit).
    phase : str
        ``setup``, ``quick`` (a revisit alone) or ``changes`` (a revisit, its diff and the report).
    seconds : float
        Wall time of the revisit (and its diff and report), seconds.
    rss_mb, hwm_mb : float
        Resident set and its peak so far (``VmRSS``, ``VmHWM``), MB (10^6 bytes).
    threads_native : int
        Threads of the process (``/proc/self/task``).
    threads_python : int
        :func:`threading.active_count`.
    fds : int
        Open file descriptors (``/proc/self/fd``, without the one that lists them).
    python_objects : int
        Objects tracked by Python's garbage collector after a full collection (:func:`gc.get_objects`).
    tmp_left : int
        Entries of the temporary folder and ``.tmp-*`` under the campaign that were not there before the run.
    verified : bool
        ``campaign verify`` found no error, none of them in this revisit's visit.
    converged : bool
        The relocation met its stop rule (a visit is written either way).
    visit : str
        The visit's folder name ('' when the revisit failed).
    detail : str
        The failure or verify problem ('' when none).
    afd_px : float
        The simulator's true AFD at the reached pose (drift of the relocation; nan when unknown).
    """

    index: int
    phase: str
    seconds: float
    rss_mb: float
    hwm_mb: float
    threads_native: int
    threads_python: int
    fds: int
    tmp_left: int
    python_objects: int = 0
    verified: bool = True
    converged: bool = True
    visit: str = ""
    detail: str = ""
    afd_px: float = float("nan")

    def to_dict(self) -> dict:
        """The sample as JSON (rounded)."""
        d = asdict(self)
        for key in ("seconds", "rss_mb", "hwm_mb", "afd_px"):
            d[key] = round(d[key], 2) if np.isfinite(d[key]) else None
        return d


def proc_status_mb(text: str, key: str) -> float:
    """The ``key`` line of a ``/proc/<pid>/status`` text (``VmRSS:  1234 kB``) in MB (10^6 bytes); nan if absent."""
    for line in text.splitlines():
        if line.startswith(key + ":"):
            parts = line.split()
            return float(parts[1]) * 1024 / 1e6
    return float("nan")


@dataclass(frozen=True)
class TempBaseline:
    """What the temporary folder and the campaign held before the run (their later new entries are "left")."""

    tmp_dir: Path
    tmp_entries: frozenset[str]
    campaign: Path
    campaign_tmp: frozenset[Path]

    @classmethod
    def take(cls, campaign: Path) -> TempBaseline:
        """The entries now: of :func:`tempfile.gettempdir` and the ``.tmp-*`` under ``campaign``."""
        tmp = Path(tempfile.gettempdir())
        return cls(tmp, frozenset(os.listdir(tmp)), Path(campaign), frozenset(_campaign_tmp(Path(campaign))))

    def left(self) -> list[str]:
        """New entries since :meth:`take`: temporary-folder names, then campaign paths (relative)."""
        new_tmp = sorted(set(os.listdir(self.tmp_dir)) - self.tmp_entries)
        new_camp = sorted(
            p.relative_to(self.campaign).as_posix() for p in _campaign_tmp(self.campaign) if p not in self.campaign_tmp
        )
        return new_tmp + new_camp


def _campaign_tmp(campaign: Path) -> set[Path]:
    return set(campaign.rglob(TMP_PREFIX + "*")) if campaign.is_dir() else set()


def sample_resources(
    *, index: int, phase: str, seconds: float, baseline: TempBaseline, outcome: dict | None = None
) -> ResourceSample:
    """Sample the process now (after a full garbage collection: cyclic garbage is not a leak).

    ``outcome``: the revisit's ``verified``, ``converged``, ``visit``, ``detail``, ``afd_px`` (:class:`ResourceSample`).
    """
    gc.collect()
    status = Path("/proc/self/status").read_text()
    return ResourceSample(
        index=index,
        phase=phase,
        seconds=seconds,
        rss_mb=proc_status_mb(status, "VmRSS"),
        hwm_mb=proc_status_mb(status, "VmHWM"),
        threads_native=len(os.listdir("/proc/self/task")),
        threads_python=threading.active_count(),
        fds=len(os.listdir("/proc/self/fd")) - 1,
        tmp_left=len(baseline.left()),
        python_objects=len(gc.get_objects()),
        **(outcome or {}),
    )


def growth_per_revisit(values: Sequence[float], *, warmup: int) -> float:
    """Slope of the least-squares line through ``values[warmup:]`` against the revisit number (units/revisit).

    Rule: fewer than two values after the warm-up give 0.0 (no slope can be fitted: nothing measured grows).
    """
    y = np.asarray(values[warmup:], dtype=float)
    y = y[np.isfinite(y)]
    if len(y) < 2:
        return 0.0
    x = np.arange(len(y), dtype=float)
    return float(np.polyfit(x, y, 1)[0])


def _rounded(value: float, digits: int) -> float:
    """``value`` rounded; a flat series' slope of -1e-17 reads 0.0, not -0.0."""
    return round(value, digits) + 0.0


def summarize_samples(samples: Sequence[ResourceSample], *, warmup: int) -> dict:
    """The soak's resource keys over the revisits (``index`` >= 1) of ``samples``.

    ``rss_growth_mb_per_revisit`` is fitted over the ``quick`` revisits after ``warmup``;
    ``rss_growth_mb_per_change_revisit`` over the ``changes`` revisits after their first (its report
    compares every earlier visit: a one-off), ``fds_growth_per_revisit`` like the first.
    """
    revisits = [s for s in samples if s.index >= 1]
    quick = [s for s in revisits if s.phase == "quick"]
    changes = [s for s in revisits if s.phase == "changes"]
    every = list(samples)
    rss = [s.rss_mb for s in quick]
    afd = [s.afd_px for s in revisits if np.isfinite(s.afd_px)]
    return {
        "rss_growth_mb_per_revisit": _rounded(growth_per_revisit([s.rss_mb for s in quick], warmup=warmup), 3),
        "rss_growth_mb_per_change_revisit": _rounded(growth_per_revisit([s.rss_mb for s in changes], warmup=1), 3),
        "fds_growth_per_revisit": _rounded(growth_per_revisit([s.fds for s in quick], warmup=warmup), 3),
        "python_objects_growth_per_revisit": _rounded(
            growth_per_revisit([s.python_objects for s in quick], warmup=warmup), 1
        ),
        "rss_largest_step_mb": round(float(max(np.diff(rss), default=0.0)), 1) if len(rss) > 1 else 0.0,
        "afd_px_max": round(max(afd), 2) if afd else None,
        "afd_growth_px_per_revisit": _rounded(growth_per_revisit(afd, warmup=0), 4),
        "rss_start_mb": round(revisits[0].rss_mb, 1) if revisits else 0.0,
        "rss_end_mb": round(revisits[-1].rss_mb, 1) if revisits else 0.0,
        "rss_peak_mb": round(max((s.hwm_mb for s in every), default=0.0), 1),
        "threads_max": max((s.threads_native for s in every), default=0),
        "threads_python_max": max((s.threads_python for s in every), default=0),
        "threads_end": revisits[-1].threads_native if revisits else 0,
        "fds_max": max((s.fds for s in every), default=0),
        "fds_end": revisits[-1].fds if revisits else 0,
        "tmp_files_left": revisits[-1].tmp_left if revisits else 0,
        "tmp_files_left_max": max((s.tmp_left for s in revisits), default=0),
    }
