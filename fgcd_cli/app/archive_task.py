"""One archive task: analyse one visit (diff + AFD) if its stored analysis is not up to date.

This is the function ``fgcd archive analyze`` sends to Dask workers
(:mod:`fgcd_cli.app.archive`); it calls the diff use case
(:func:`fgcd_cli.app.diff.run_campaign`), never a copy of it. It never raises:
a failing visit comes back as a :class:`VisitOutcome` with one line of reason,
so that the other visits go on (docs/archive.md, "Failures").
"""

from __future__ import annotations

import logging
import resource
import time
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from fgcd_cli.archive.discovery import VisitKey
from fgcd_cli.archive.freshness import AnalysisOptions, Freshness, analysis_inputs, freshness, verify_inputs
from fgcd_cli.errors import OUT_OF_MEMORY, FgcdError, is_out_of_memory, os_error_line

__all__ = ["VisitStatus", "VisitOutcome", "analyze_visit", "visit_freshness"]

# This module is imported by every worker that runs a visit: from then on the worker logs errors only,
# so that the tasks Ctrl-C cancels are not warnings on the user's terminal.
logging.getLogger("distributed.worker").setLevel(logging.ERROR)


class VisitStatus(StrEnum):
    """How one visit's task ended."""

    DONE = "done"
    SKIPPED = "skipped"
    FAILED = "failed"


@dataclass(frozen=True, kw_only=True)
class VisitOutcome:
    """The result of one visit's task.

    Attributes
    ----------
    key : VisitKey
    status : VisitStatus
    reason : str
        One line: why it failed, or why it was (re)done (a :class:`Freshness` value).
    regions : int or None
        Change regions found (done visits).
    seconds : float
        Wall time of the task on its worker, s.
    worker_peak_rss_mb : float
        Peak resident memory of the worker process so far, MiB (``getrusage`` maxrss).
    """

    key: VisitKey
    status: VisitStatus
    reason: str = ""
    regions: int | None = None
    seconds: float = 0.0
    worker_peak_rss_mb: float = 0.0

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {
            "campaign": self.key.campaign,
            "station": self.key.station,
            "visit": self.key.visit,
            "status": self.status.value,
            "reason": self.reason,
            "regions": self.regions,
            "seconds": round(self.seconds, 3),
            "worker_peak_rss_mb": round(self.worker_peak_rss_mb, 1),
        }


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _open(key: VisitKey):
    from fgcd_cli.campaign.store import open_campaign

    station = open_campaign(Path(key.campaign)).station(key.station)
    return station.reference(), station.visit(key.visit)


def visit_freshness(key: VisitKey, options: AnalysisOptions) -> Freshness:
    """Where the visit's stored analysis stands (reads manifests only; errors propagate)."""
    reference, visit = _open(key)
    return freshness(reference, visit, options)


def _analyze(key: VisitKey, options: AnalysisOptions, force: bool, t0: float) -> VisitOutcome:
    from fgcd_cli.app.diff import CampaignDiffRequest, run_campaign

    reference, visit = _open(key)
    state = freshness(reference, visit, options)
    if state == Freshness.UP_TO_DATE and not force:
        return VisitOutcome(
            key=key,
            status=VisitStatus.SKIPPED,
            reason=state.value,
            seconds=time.perf_counter() - t0,
            worker_peak_rss_mb=_peak_rss_mb(),
        )
    inputs = analysis_inputs(reference, visit)
    verify_inputs(reference, visit, inputs)
    data = run_campaign(
        request=CampaignDiffRequest(
            campaign=Path(key.campaign),
            station=key.station,
            visit=key.visit,
            mm_per_px=options.mm_per_px,
            register=options.register,
            edge_check_px=options.edge_check_px,
            min_contrast=options.min_contrast,
            geometry=options.geometry,
            force=force,
        )
    )
    # run_campaign wrote changes/analysis.json last (the options and inputs above): its presence means "complete"
    return VisitOutcome(
        key=key,
        status=VisitStatus.DONE,
        reason="forced" if force else state.value,
        regions=len(data.get("regions") or []),
        seconds=time.perf_counter() - t0,
        worker_peak_rss_mb=_peak_rss_mb(),
    )


def analyze_visit(key: VisitKey, options: AnalysisOptions = AnalysisOptions(), force: bool = False) -> VisitOutcome:
    """Analyse one visit unless its stored analysis is up to date (``force``: always); never raises.

    Parameters
    ----------
    key : VisitKey
    options : AnalysisOptions
    force : bool
        Re-do the analysis even when up to date.

    Returns
    -------
    VisitOutcome
        ``done`` (products and ``changes/analysis.json`` written), ``skipped`` (up to
        date) or ``failed`` with one line of reason (the error's message).
    """
    t0 = time.perf_counter()
    try:
        return _analyze(key, options, force, t0)
    except Exception as exc:  # one visit's failure is reported, never stops the others
        if isinstance(exc, FgcdError):
            text = str(exc)
        elif isinstance(exc, OSError):  # the CLI's line for the same error (README, "Errors")
            text = os_error_line(exc)
        elif is_out_of_memory(exc):
            text = OUT_OF_MEMORY
        else:
            text = f"{type(exc).__name__}: {exc}"
        line = (text.strip().splitlines() or [type(exc).__name__])[0]
        return VisitOutcome(
            key=key,
            status=VisitStatus.FAILED,
            reason=line,
            seconds=time.perf_counter() - t0,
            worker_peak_rss_mb=_peak_rss_mb(),
        )
