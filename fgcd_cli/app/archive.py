"""The archive use case (``fgcd archive analyze``): every visit of every campaign under the roots, on Dask.

One task per visit (:func:`fgcd_cli.app.archive_task.analyze_visit`), run on
Dask distributed: an embedded ``LocalCluster`` of worker processes by default,
or an existing scheduler (``tcp://HOST:PORT``). Each task reads its inputs from
the campaign, skips a visit whose stored analysis is up to date, and writes its
products into the visit with ``changes/analysis.json`` last; a failing visit
comes back with one line of reason while the others go on. Ctrl-C cancels the
remaining tasks and closes an embedded cluster (docs/archive.md, "Where the tasks run").
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from fgcd_cli.app.archive_task import VisitOutcome, VisitStatus, analyze_visit, visit_freshness
from fgcd_cli.archive.discovery import VisitKey, archive_visits, find_campaigns
from fgcd_cli.archive.freshness import AnalysisOptions, Freshness
from fgcd_cli.errors import FgcdError, UserInputError

__all__ = ["ArchiveRequest", "ArchiveResult", "PlannedVisit", "analyze_archive", "plan_archive", "dask_client"]

ProgressCallback = Callable[[int, int, str], None]
WORKER_WAIT_S = 30.0
"""How long an existing scheduler may take to show its first worker, s."""


@dataclass(frozen=True, kw_only=True)
class ArchiveRequest:
    """An archive analysis (``fgcd archive analyze ROOT...``).

    Attributes
    ----------
    roots : list of Path
        Folders searched for campaigns (a campaign folder itself is a root too).
    workers : int
        Worker processes of the embedded LocalCluster (ignored with ``scheduler``).
    scheduler : str or None
        Address of an existing Dask scheduler (``tcp://HOST:PORT``); None: an embedded LocalCluster.
    force : bool
        Re-do every visit, up to date or not.
    options : AnalysisOptions
        The diff's options (part of the up-to-date key).
    """

    roots: list[Path]
    workers: int = 2
    scheduler: str | None = None
    force: bool = False
    options: AnalysisOptions = field(default_factory=AnalysisOptions)


@dataclass(frozen=True, kw_only=True)
class PlannedVisit:
    """A visit of the archive and where its stored analysis stands (``--dry-run``)."""

    key: VisitKey
    state: Freshness | None
    problem: str = ""
    forced: bool = False

    @property
    def needs_work(self) -> bool:
        """True when the analysis would (re)do this visit."""
        return self.forced or self.state != Freshness.UP_TO_DATE

    def to_dict(self) -> dict:
        """JSON-ready form."""
        return {
            "campaign": self.key.campaign,
            "station": self.key.station,
            "visit": self.key.visit,
            "state": self.state.value if self.state else None,
            "problem": self.problem,
            "to_do": self.needs_work,
        }


@dataclass(frozen=True, kw_only=True)
class ArchiveResult:
    """What an archive analysis did.

    Attributes
    ----------
    campaigns : int
    outcomes : list of VisitOutcome
        One per visit, in archive order.
    scheduler : str
        The scheduler's address the tasks ran on.
    workers : int
        Workers the scheduler had when the tasks were submitted.
    start_s, run_s : float
        Time to start (or connect to) the cluster, and from the first submission to the last result, s.
    """

    campaigns: int
    outcomes: list[VisitOutcome]
    scheduler: str
    workers: int
    start_s: float
    run_s: float

    def count(self, status: VisitStatus) -> int:
        """Visits that ended with ``status``."""
        return sum(o.status == status for o in self.outcomes)

    def to_dict(self) -> dict:
        """JSON-ready form (the ``--json`` output)."""
        return {
            "campaigns": self.campaigns,
            "visits": len(self.outcomes),
            "done": self.count(VisitStatus.DONE),
            "skipped": self.count(VisitStatus.SKIPPED),
            "failed": self.count(VisitStatus.FAILED),
            "scheduler": self.scheduler,
            "workers": self.workers,
            "start_s": round(self.start_s, 3),
            "run_s": round(self.run_s, 3),
            "outcomes": [o.to_dict() for o in self.outcomes],
        }


def _check(request: ArchiveRequest) -> None:
    if not request.roots:
        raise UserInputError("give at least one archive root (a folder holding campaigns)")
    if request.scheduler is None and not 1 <= request.workers <= 256:
        raise UserInputError(f"--workers must be between 1 and 256, got {request.workers}")
    if request.scheduler is not None and not request.scheduler.startswith(("tcp://", "tls://", "inproc://")):
        raise UserInputError(f"--scheduler must be an address like tcp://HOST:PORT, got {request.scheduler!r}")


def plan_archive(request: ArchiveRequest) -> tuple[int, list[PlannedVisit]]:
    """The campaigns found and every visit with where its analysis stands (reads manifests only)."""
    _check(request)
    campaigns = find_campaigns(request.roots)
    planned = []
    for key in archive_visits(campaigns):
        try:
            planned.append(PlannedVisit(key=key, state=visit_freshness(key, request.options), forced=request.force))
        except FgcdError as exc:
            planned.append(PlannedVisit(key=key, state=None, problem=str(exc).splitlines()[0], forced=request.force))
    return len(campaigns), planned


@contextmanager
def dask_client(*, scheduler: str | None, workers: int) -> Iterator:
    """A ``distributed.Client`` on ``scheduler``, or on an embedded LocalCluster of ``workers`` processes.

    The LocalCluster's workers are separate processes (one thread each: the diff
    is CPU-bound and holds the GIL in places), listen on 127.0.0.1 only and serve
    no dashboard (the scheduler's HTTP endpoint takes a free local port). Closed on exit, Ctrl-C included.
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise UserInputError("fgcd archive needs Dask: pip install 'fgcd[archive]'") from None
    logging.getLogger("distributed").setLevel(logging.ERROR)
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="5s")
        except (OSError, TimeoutError) as exc:  # a network failure: the operating-system exit code (README)
            reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise FgcdError(f"cannot reach the Dask scheduler at {scheduler} ({reason})") from None
        try:
            try:  # a scheduler without workers would hold the tasks for ever
                client.wait_for_workers(1, timeout=WORKER_WAIT_S)
            except TimeoutError:
                raise FgcdError(
                    f"the Dask scheduler at {scheduler} has no worker (waited {WORKER_WAIT_S:.0f} s); "
                    f"start some with `dask worker {scheduler}`"
                ) from None
            yield client
        finally:
            client.close()
        return
    # The scheduler's HTTP endpoint (health, metrics) is served even with the dashboard off: on a free local port.
    with (
        LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def _label(result_counts: dict[VisitStatus, int]) -> str:
    return (
        f"analysing visits ({result_counts[VisitStatus.DONE]} done, {result_counts[VisitStatus.SKIPPED]} skipped, "
        f"{result_counts[VisitStatus.FAILED]} failed)"
    )


def _lost(key: VisitKey, exc: BaseException) -> VisitOutcome:
    """A task the cluster could not finish (its worker died, the connection was lost)."""
    text = (str(exc).strip().splitlines() or [""])[0]
    return VisitOutcome(key=key, status=VisitStatus.FAILED, reason=f"the task was lost ({type(exc).__name__}: {text})")


def _run_tasks(
    client,
    keys: list[VisitKey],
    request: ArchiveRequest,
    on_progress: ProgressCallback | None,
    on_visit: Callable[[VisitOutcome], None] | None,
) -> dict[VisitKey, VisitOutcome]:
    from distributed import as_completed

    counts = {status: 0 for status in VisitStatus}
    run = uuid.uuid4().hex[:8]  # task keys unique to this run: another client of the same cluster has its own
    futures = {
        client.submit(
            analyze_visit, key, request.options, request.force, pure=False, key=f"fgcd-visit-{run}-{i}-{key.label}"
        ): key
        for i, key in enumerate(keys)
    }
    outcomes: dict[VisitKey, VisitOutcome] = {}
    try:
        for future in as_completed(list(futures)):
            key = futures[future]
            try:
                outcome = future.result()
            except Exception as exc:  # a worker died or the scheduler went away: this visit only
                outcome = _lost(key, exc)
            outcomes[key] = outcome
            counts[outcome.status] += 1
            if on_visit is not None:
                on_visit(outcome)
            if on_progress is not None:
                on_progress(len(outcomes), len(keys), _label(counts))
    except BaseException:
        client.cancel(list(futures))
        raise
    return outcomes


def analyze_archive(
    request: ArchiveRequest,
    *,
    on_progress: ProgressCallback | None = None,
    on_visit: Callable[[VisitOutcome], None] | None = None,
) -> ArchiveResult:
    """Analyse every visit under ``request.roots`` on Dask; up-to-date visits are skipped.

    Parameters
    ----------
    request : ArchiveRequest
    on_progress : callable, optional
        ``on_progress(finished, total, label)`` after each visit (label: counts of done, skipped, failed).
    on_visit : callable, optional
        Called with each :class:`VisitOutcome` as it arrives (failures are reported as they happen).
    """
    _check(request)
    campaigns = find_campaigns(request.roots)
    keys = archive_visits(campaigns)
    t0 = time.perf_counter()
    with dask_client(scheduler=request.scheduler, workers=request.workers) as client:
        info = client.scheduler_info()
        start_s = time.perf_counter() - t0
        if on_progress is not None:
            on_progress(0, len(keys), _label({s: 0 for s in VisitStatus}))
        t1 = time.perf_counter()
        outcomes = _run_tasks(client, keys, request, on_progress, on_visit) if keys else {}
        run_s = time.perf_counter() - t1
    return ArchiveResult(
        campaigns=len(campaigns),
        outcomes=[outcomes[k] for k in keys],
        scheduler=str(info.get("address", request.scheduler or "")),
        workers=len(info.get("workers", {})),
        start_s=start_s,
        run_s=run_s,
    )
