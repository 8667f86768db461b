"""One alignment of the current VSE state to the reference: fast, then fine (docs/alignment.md, "Fast alignment", "Fine-grained alignment").

:func:`align_once` is the loop's default :class:`Aligner`; the loop receives
an aligner as a value (``LoopContext.aligner``), so a stand-in replaces it
without patching this module.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.fine_config import FineAlignConfig
from fgcd_cli.relocation.config import ReferenceData
from fgcd_cli.relocation.enums import EstimateStage
from fgcd_cli.relocation.protocols import CameraModel
from fgcd_core.sim3 import Sim3

__all__ = ["AlignmentEstimate", "AlignmentProblem", "Aligner", "align_once", "local_cloud", "scaled_pose"]


@dataclass(frozen=True, kw_only=True)
class AlignmentEstimate:
    """One published alignment.

    Attributes
    ----------
    T_ref_cur : Sim3
        The session's metric frame in the reference frame.
    stage : EstimateStage
        ``"fast"`` or ``"fine"``.
    ok, reason :
        The health check's verdict.
    vse_frame : int
        ``frames_processed`` of the VSE state it used.
    seconds : float
        Wall time of this stage.
    serial : int
        Increasing publication number.
    degenerate : bool
        The health check found the geometry degenerate (not noise: the scene).
    """

    T_ref_cur: Sim3
    stage: EstimateStage | str
    ok: bool
    reason: str
    vse_frame: int
    seconds: float
    serial: int
    degenerate: bool = False


@dataclass(frozen=True, kw_only=True)
class AlignmentProblem:
    """What stays fixed across the alignments of one run.

    Attributes
    ----------
    reference : ReferenceData
    ref_index : fgcd_cli.alignment.ReferenceIndex or None
        Search structure over the reference cloud (``None``: the raw points).
    camera : PinholeCamera or None
        Intrinsics of the current camera (the fine stage's photometric term).
    scale : float
        Metres per VSE map unit of this session.
    fine : bool
        Run the fine stage after a trustworthy fast one.
    recent_keyframes : int
        Keyframes whose points make the local cloud (:func:`local_cloud`).
    fast_config, fine_config : FastAlignConfig, FineAlignConfig
        Options of the two stages.
    """

    reference: ReferenceData
    ref_index: object
    camera: CameraModel | None
    scale: float
    fine: bool = True
    recent_keyframes: int = 6
    fast_config: FastAlignConfig = FastAlignConfig()
    fine_config: FineAlignConfig = FineAlignConfig()


class Aligner(Protocol):
    """Aligns one VSE state; returns the estimates it produced, in order (fast, then fine)."""

    def __call__(self, *, state, problem: AlignmentProblem, init: Sim3, serial: int = 0) -> list[AlignmentEstimate]: ...  # noqa: D102


def scaled_pose(T_map_cam: np.ndarray, scale: float) -> np.ndarray:
    """A VSE pose (map units) in the session's metric frame: translation times ``scale``, (4, 4)."""
    T = np.array(T_map_cam, dtype=float)
    T[:3, 3] *= scale
    return T


def local_cloud(state, recent_keyframes: int, *, min_points: int = 3000) -> np.ndarray:
    """Cloud points of the most recent keyframes (the local map around the current camera), (N, 3) map units.

    A monocular map drifts in scale over a session; the points measured from
    the latest keyframes are consistent with the latest camera pose, which is
    what the adjustment needs. Falls back to the whole cloud when the local
    part is too small.
    """
    pts = np.asarray(state.cloud.points, dtype=float)
    ids = np.asarray(getattr(state.cloud, "keyframe_ids", np.zeros(0)))
    if recent_keyframes <= 0 or len(ids) != len(pts) or not state.keyframes:
        return pts
    recent = {kf.id for kf in state.keyframes[-recent_keyframes:]}
    keep = np.isin(ids, list(recent))
    return pts[keep] if keep.sum() >= min_points else pts


def align_once(*, state, problem: AlignmentProblem, init: Sim3, serial: int = 0) -> list[AlignmentEstimate]:
    """Fast (then fine) alignment of one VSE state; returns the estimates it produced.

    The fine stage runs only after a trustworthy fast one and with two keyframes
    or more; its estimate is published with ``serial + 1``.
    """
    from fgcd_cli.alignment.fast import fast_align
    from fgcd_cli.alignment.fine import fine_align

    out: list[AlignmentEstimate] = []
    scale, ref_index = problem.scale, problem.ref_index
    cur_points = local_cloud(state, problem.recent_keyframes) * scale
    t0 = time.monotonic()
    fast = fast_align(cur_points, ref_index, init=init, config=problem.fast_config)
    out.append(
        AlignmentEstimate(
            T_ref_cur=fast.T_ref_cur,
            stage=EstimateStage.FAST,
            ok=bool(fast.health.ok),
            reason=fast.health.reason,
            vse_frame=state.frames_processed,
            seconds=time.monotonic() - t0,
            serial=serial,
            degenerate=bool(fast.health.degenerate),
        )
    )
    if problem.fine and fast.health.ok and len(state.keyframes) >= 2:
        t1 = time.monotonic()
        kfs = [(scaled_pose(kf.T_map_cam, scale), kf.image) for kf in state.keyframes[-6:]]
        res = fine_align(
            ref_points=ref_index if ref_index is not None else problem.reference.points,
            ref_intensities=problem.reference.intensities,
            cur_keyframes=kfs,
            camera=problem.camera,
            init=fast.T_ref_cur,
            cur_points=cur_points,
            config=problem.fine_config,
        )
        out.append(
            AlignmentEstimate(
                T_ref_cur=res.T_ref_cur,
                stage=EstimateStage.FINE,
                ok=bool(res.health.ok),
                reason=res.health.reason,
                vse_frame=state.frames_processed,
                seconds=time.monotonic() - t1,
                serial=serial + 1,
                degenerate=bool(res.health.degenerate),
            )
        )
    return out
