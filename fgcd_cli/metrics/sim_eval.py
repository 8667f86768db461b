"""Evaluation against the simulator's ground truth (evaluation code only).

Algorithms never call this; commands running on the simulator attach it to
the relocation log ("truth" fields) and to the observation's
``evaluation/sim_truth.json`` so that benchmarks and reports can score a run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgcd_cli.campaign.schema import SIM_TRUTH
from fgcd_core.se3 import pose_distance

__all__ = ["reference_truth", "RelocationEvaluator", "change_ids_in_reference", "count_changes_found"]


def reference_truth(sim_rig) -> dict:
    """What evaluation needs to remember of a simulated reference capture."""
    gt = sim_rig.ground_truth
    return {
        "T_world_cam": np.asarray(gt.T_world_cam_true()).tolist(),
        "T_flange_cam": np.asarray(gt.T_flange_cam_true()).tolist(),
        "intrinsics": gt.intrinsics_true().to_dict(),
    }


@dataclass
class RelocationEvaluator:
    """True pose error and true AFD of the simulated camera against the reference."""

    sim_rig: object
    T_world_camref: np.ndarray

    @classmethod
    def from_reference(cls, sim_rig, reference_observation) -> RelocationEvaluator | None:
        """Build from a reference observation captured on the simulator (None otherwise)."""
        if not reference_observation.has(SIM_TRUTH):
            return None
        truth = reference_observation.json(SIM_TRUTH)
        return cls(sim_rig, np.array(truth["T_world_cam"], dtype=float))

    def evaluate(self) -> dict:
        """Truth of the current camera: pose error (mm, deg) and AFD (px)."""
        gt = self.sim_rig.ground_truth
        T_cur = np.asarray(gt.T_world_cam_true())
        mm, deg = pose_distance(T_cur, self.T_world_camref)
        afd = float(gt.true_afd_px(self.T_world_camref, T_cur, gt.intrinsics_true()))
        return {"pose_err_mm": mm, "pose_err_deg": deg, "afd_px": afd}

    def summary(self) -> dict:
        """Final truth written with a visit."""
        out = self.evaluate()
        out["T_world_cam"] = np.asarray(self.sim_rig.ground_truth.T_world_cam_true()).tolist()
        out["T_world_camref"] = self.T_world_camref.tolist()
        return out


def change_truth_in_reference(sim_rig, T_world_camref: np.ndarray, camera_used) -> np.ndarray:
    """Ground-truth change mask in the reference image as fgcd stores it (HxW bool).

    Rendered at the true reference camera with the true intrinsics, then
    remapped like the stored images (undistorted with the calibrated camera
    ``camera_used``, a PinholeCamera with its distortion).
    """
    gt = sim_rig.ground_truth
    mask = gt.change_mask(np.asarray(T_world_camref, dtype=float), gt.intrinsics_true())
    if camera_used is not None and camera_used.has_distortion:
        from fgcd_cli.vse.undistort import Undistorter

        mask = Undistorter(camera_used).depth(mask.astype(np.float32)) > 0.5
    return np.asarray(mask, dtype=bool)


def score_change_detection(found_mask: np.ndarray, truth_mask: np.ndarray) -> dict:
    """Pixel scores and how many true change blobs a found region touches (``change_scores.region_counts``:
    regions 8-connected, as the detector's are)."""
    from fgcd_cli.metrics.change_scores import binary_scores, region_counts

    s = binary_scores(found_mask.astype(bool), truth_mask.astype(bool))
    counts = region_counts(found_mask, truth_mask)
    out = {k: float(v) for k, v in s.__dict__.items() if isinstance(v, (int, float))}
    out.update(
        {
            "true_changes": counts.changes_true,
            "true_changes_found": counts.changes_found,
            "found_regions": counts.regions,
            "false_regions": counts.false_regions,
        }
    )
    return out


def change_ids_in_reference(sim_rig, T_world_camref: np.ndarray, camera_used) -> np.ndarray:
    """Which injected change each pixel of the stored reference image shows (HxW int32, 0 = none).

    Evaluation only. Like :func:`change_truth_in_reference`, but
    keeping each change's identity (1 + its index among the injected changes), remapped
    like the stored images with a nearest-neighbour lookup so that identities never mix.
    """
    gt = sim_rig.ground_truth
    ids = gt.change_ids(np.asarray(T_world_camref, dtype=float), gt.intrinsics_true())
    if camera_used is not None and camera_used.has_distortion:
        from fgcd_cli.vse.undistort import Undistorter

        ids = Undistorter(camera_used).depth(ids.astype(np.float32))
    return np.rint(ids).astype(np.int32)


def count_changes_found(found: np.ndarray, truth_ids: np.ndarray, *, injected: int) -> dict:
    """How many injected changes a change mask found, counted by change, not by blob.

    A change seen as several pieces (a crack broken by the relief, a stain cut by a
    shadow) is still one change, found when any of its pixels is found.

    Parameters
    ----------
    found : ndarray, HxW bool; the tool's change mask (reference image).
    truth_ids : ndarray, HxW int; 0 where no change, else the change's identity (1-based).
    injected : int, keyword-only; changes injected into the world (some may be out of view).

    Returns
    -------
    dict with ``injected_changes``, ``true_changes`` (injected changes in view of the
    reference image) and ``true_changes_found``.
    """
    found = np.asarray(found, dtype=bool)
    ids = np.asarray(truth_ids)
    in_view = set(np.unique(ids[ids > 0]).tolist())
    hit = set(np.unique(ids[found & (ids > 0)]).tolist())
    return {"injected_changes": int(injected), "true_changes": len(in_view), "true_changes_found": len(hit)}
