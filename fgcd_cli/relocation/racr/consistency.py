"""Every 3D estimate of one run is an estimate of the same transform: a test that they agree.

The alignment's ``T_ref_cur`` maps the session's map frame into the reference
frame. The map frame does not move with the camera (the VSE is not
re-initialised during the loop), so every trustworthy estimate of a run
estimates one and the same transform, each with its own error. Applied to the
same camera pose (the VSE's current one), two estimates place the camera at
two points whose distance has an RMS of ``sqrt(2) sigma_3d`` when their errors
are independent (less when they are correlated, as successive alignments of a
growing cloud are). Two estimates farther apart than ``k sqrt(2) sigma_3d``
(:func:`~fgcd_cli.relocation.stop_rule.estimates_agree`) are not both estimates
of one transform: the alignment's estimate moves with the camera, e.g. a cloud
that slides along a near-symmetry of the object (a statue's orbit about its own
axis) and follows each motion it commands (docs/relocation.md, "Estimates that
follow the camera").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcd_cli.relocation.adjustment import camera_in_reference
from fgcd_cli.relocation.stop_rule import estimates_agree
from fgcd_core.sim3 import Sim3

__all__ = ["EstimateSpread", "estimate_spread"]


@dataclass(frozen=True, kw_only=True)
class EstimateSpread:
    """The largest disagreement between a new estimate and the run's earlier ones.

    Attributes
    ----------
    agree : bool
        Every earlier estimate agrees with the new one within ``bound_mm``.
    distance_mm : float
        Largest distance between the camera positions the new estimate and an earlier one give to the
        same camera pose, mm (0 without earlier estimates).
    bound_mm : float
        ``k sqrt(2) sigma_3d``, mm.
    against : int
        Index of the earlier estimate farthest from the new one (-1 without earlier estimates).
    """

    agree: bool
    distance_mm: float
    bound_mm: float
    against: int


def estimate_spread(
    new: Sim3, earlier: list[Sim3], T_cur_cam: np.ndarray, *, sigma_mm: float, k: float
) -> EstimateSpread:
    """Compare a new estimate of ``T_ref_cur`` with the run's earlier ones at one camera pose.

    Parameters
    ----------
    new : Sim3
        The new estimate of ``T_ref_cur``.
    earlier : list of Sim3
        The run's earlier trustworthy estimates of the same transform.
    T_cur_cam : (4, 4) ndarray
        The camera pose in the session's metric frame (VSE pose, translation times the session scale), metres.
    sigma_mm : float
        1-sigma uncertainty (RMS radius) of one estimate's camera position, mm.
    k : float
        Allowed multiple of the combined uncertainty (``RelocationConfig.agreement_k``).

    Returns
    -------
    EstimateSpread
        ``agree`` is True when ``sigma_mm`` is not finite (no model, nothing to test).
    """
    if not earlier or not np.isfinite(sigma_mm):
        return EstimateSpread(agree=True, distance_mm=0.0, bound_mm=float("nan"), against=-1)
    here = 1000.0 * camera_in_reference(new, T_cur_cam)[:3, 3]
    there = [1000.0 * camera_in_reference(other, T_cur_cam)[:3, 3] for other in earlier]
    # every pair has the same bound (one sigma per estimate): the farthest earlier estimate decides
    distances = [float(np.linalg.norm(here - p)) for p in there]
    worst = int(np.argmax(distances))
    ok, dist, bound = estimates_agree(here, sigma_mm, there[worst], sigma_mm, k=k)
    return EstimateSpread(agree=ok, distance_mm=dist, bound_mm=bound, against=worst)
