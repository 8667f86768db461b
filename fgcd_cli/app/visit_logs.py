"""What a visit's logs say, read for its diff report: the coarse and relocation log rows, the stated residual.

:func:`coarse_log_rows` and :func:`relocation_log_rows` give the rows the report's
figures plot (the simulator's truth only under ``*_true`` keys);
:func:`relocation_residual_mm` and :func:`relocation_residual_text` give the
relocation's own estimate of what remained, never the simulator's truth.
"""

from __future__ import annotations

import json

from fgcd_cli.campaign import schema


def coarse_log_rows(visit) -> list[dict] | None:
    """The visit's coarse stage log (``coarse.jsonl``) as rows, or None when the stage did not run."""
    if not visit.has(schema.COARSE_LOG):
        return None
    lines = visit.bytes(schema.COARSE_LOG).decode("utf-8").splitlines()
    return [json.loads(line) for line in lines if line.strip()] or None


def relocation_log_rows(visit) -> list[dict] | None:
    """The visit's relocation log as plot rows: each logged row, its simulator truth (if any) under ``*_true`` keys.

    The loop's own estimates keep their names (``afd_est_px``, ``offset_mm``, ``offset_deg``);
    the ``truth`` entry a simulated run logs (``pose_err_mm``, ``pose_err_deg``, ``afd_px``)
    becomes ``pose_err_mm_true``, ``pose_err_deg_true``, ``afd_px_true``, so that no
    figure can show truth under an estimate's name. None without a log.
    """
    if not visit.has(schema.RELOCATION_LOG):
        return None
    rows = []
    for line in visit.bytes(schema.RELOCATION_LOG).decode("utf-8").splitlines():
        if line.strip():
            row = json.loads(line)
            truth = row.pop("truth", None) or {}
            rows.append({**row, **{f"{key}_true": value for key, value in truth.items()}})
    return rows or None


def relocation_residual_mm(visit) -> float | None:
    """The relocation's own estimate of the remaining camera offset (mm, last logged iteration), if logged."""
    if not visit.has(schema.RELOCATION_LOG):
        return None
    last = None
    for line in visit.bytes(schema.RELOCATION_LOG).decode("utf-8").splitlines():
        if line.strip():
            last = json.loads(line)
    if not last or last.get("offset_mm") is None:
        return None
    return float(last["offset_mm"])  # the row's estimate; its "truth" entry is never read here


def relocation_residual_text(visit) -> str:
    """The relocation's stated residual for the report: ``0.27 ± 0.12 mm (image estimate; ...)``.

    The visit manifest's ``relocation.residual`` (offset, uncertainty, tolerance,
    estimator, agreement) when the run stated one, else the last logged offset
    estimate alone; never the simulator's truth.
    """
    from fgcd_cli.relocation.stop_rule import Residual

    stated = (visit.metadata.get("relocation") or {}).get("residual")
    if isinstance(stated, dict):
        try:
            return Residual(**stated).text().removeprefix("residual ")
        except TypeError:
            pass  # a record from another version: fall back to the logged estimate
    residual_mm = relocation_residual_mm(visit)
    return f"{residual_mm:.2f} mm (no uncertainty logged)" if residual_mm is not None else "not logged"
