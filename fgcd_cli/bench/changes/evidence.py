"""The evidence a change report shows for each region, against the truth (issue 47, item 4): whether the
strength and the NFA rank the regions that overlap a true change above those that do not."""

from __future__ import annotations

import numpy as np

from fgcd_cli.metrics.change_scores import evidence_separation

__all__ = ["region_evidence", "separation"]


def region_evidence(result, truth: np.ndarray, mask: np.ndarray) -> list[dict]:
    """The evidence the user is shown for each reported region inside the scored area, and whether the
    region overlaps a true change: ``strength`` (peak score over the detection level) and ``minus_log10_nfa``."""
    out = []
    for region in result.regions:
        pixels = (result.labels == region.id) & mask
        if pixels.any():
            out.append(
                {
                    "strength": result.strength(region),
                    "minus_log10_nfa": -region.log10_nfa if region.log10_nfa is not None else float("nan"),
                    "true": bool((pixels & truth).any()),
                }
            )
    return out


def separation(scored: list[dict]) -> dict:
    """Pooled over the groups: how well each piece of evidence shown separates true regions from false
    ones (:func:`~fgcd_cli.metrics.change_scores.evidence_separation`; issue 47, item 4)."""
    regions = [r for g in scored for r in g["region_evidence"]]
    out = {}
    for key, name in (("strength", "region_strength_auc"), ("minus_log10_nfa", "region_nfa_auc")):
        out[name] = evidence_separation(
            [r[key] for r in regions if r["true"]], [r[key] for r in regions if not r["true"]]
        )
    return out
