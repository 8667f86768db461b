"""Initial guess of ``T_ref_cur``: the first current camera is near the reference
camera (rACR starts every revisit there), with a global multi-start fallback.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from fgcd_cli.alignment.fast import MIN_CURRENT_POINTS, as_reference, fast_align, initial_scale
from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.results import AlignmentResult
from fgcd_core.sim3 import Sim3

__all__ = ["GuessSource", "InitialGuess", "camera_prior", "initial_guess", "global_registration"]


class GuessSource(StrEnum):
    """Where an :class:`InitialGuess` came from."""

    FIRST_CAMERA = "first_camera"
    """The prior alone (no clouds given)."""
    FIRST_CAMERA_FAST = "first_camera+fast"
    """The prior refined by a fast alignment."""
    GLOBAL = "global"
    """The multi-start fallback."""


@dataclass(frozen=True, kw_only=True)
class InitialGuess:
    """Result of :func:`initial_guess`.

    Attributes
    ----------
    T_ref_cur : Sim3
        The best starting similarity (already refined by a fast alignment when clouds were given).
    source : GuessSource
    fast : AlignmentResult or None
        The fast alignment that validated it (None without clouds).
    seconds : float
    """

    T_ref_cur: Sim3
    source: GuessSource
    fast: AlignmentResult | None
    seconds: float


def camera_prior(T_ref_camref: np.ndarray, T_cur_cam0: np.ndarray, *, scale: float = 1.0) -> Sim3:
    """Similarity that puts the current session's first camera on the reference camera.

    ``T.transform_pose(T_cur_cam0) == T_ref_camref`` for the returned ``T``.
    """
    A = np.asarray(T_ref_camref, dtype=float)
    B = np.asarray(T_cur_cam0, dtype=float)
    R = A[:3, :3] @ B[:3, :3].T
    return Sim3(R, A[:3, 3] - scale * R @ B[:3, 3], scale)


def _median_depth(points: np.ndarray, T_frame_cam: np.ndarray) -> float:
    X = (points - T_frame_cam[:3, 3]) @ T_frame_cam[:3, :3]
    z = X[:, 2]
    z = z[z > 0]
    return float(np.median(z)) if len(z) else float("nan")


def _rotations_24() -> list[np.ndarray]:
    """The 24 proper rotations of the cube (signed axis permutations with det +1)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[range(3), perm] = signs
            if np.linalg.det(M) > 0:
                out.append(M)
    return out


def global_registration(
    cur_points: np.ndarray,
    reference: np.ndarray | ReferenceIndex,
    *,
    config: FastAlignConfig = FastAlignConfig(),
    around: Sim3 | None = None,
) -> AlignmentResult:
    """Multi-start fast alignment when no trustworthy prior exists.

    Starts: the 24 cube rotations about the current cloud's centroid, with
    centroids matched and the scale from the ratio of RMS radii (or, with
    ``around``, composed with that prior). Each start runs the two coarse levels;
    the start with the highest inlier ratio (ties: lower residual) is refined at
    full resolution. FPFH + RANSAC is not used: it is slower, fails on symmetric
    scenes (docs/lab/2026-11-25-code-comment-measurements.md, "Alignment") and its radii are not scale invariant.
    """
    cur = np.asarray(cur_points, dtype=float)
    ref = as_reference(reference)
    base = initial_scale(cur, ref) if around is None else around
    c = cur.mean(axis=0)
    levels = config.levels
    # The 24 starts only rank rotations: no shift search, scale refinement or minimum check
    # there (they would multiply the cost by ~10); the final run below has them.
    coarse = replace(
        config,
        levels=replace(
            levels,
            points=levels.points[:2],
            radius_rel=levels.radius_rel[:2],
            iterations=tuple(min(20, n) for n in levels.iterations[:2]),
        ),
        cold=replace(config.cold, shift_steps=0, scale_refinements=0),
        minimum_check=replace(config.minimum_check, step=0.0),
    )
    best = None
    for Q in _rotations_24():
        # Rotate the current cloud about its centroid, then apply the base prior.
        start = base @ Sim3(Q, c - Q @ c, 1.0)
        res = fast_align(cur, ref, init=start, config=coarse)
        key = (res.health.inlier_ratio, -(res.residuals.rms_mm if np.isfinite(res.residuals.rms_mm) else 1e9))
        if best is None or key > best[0]:
            best = (key, res)
    return fast_align(cur, ref, init=best[1].T_ref_cur, config=config)


def initial_guess(
    *,
    T_ref_camref: np.ndarray,
    T_cur_cam0: np.ndarray,
    cur_points: np.ndarray | None = None,
    reference: np.ndarray | ReferenceIndex | None = None,
    scale: float | None = None,
    global_fallback: bool = True,
    config: FastAlignConfig = FastAlignConfig(),
) -> InitialGuess:
    """Starting ``T_ref_cur`` for the relocation loop.

    Parameters
    ----------
    T_ref_camref : (4, 4) ndarray
        Reference camera pose in the reference frame.
    T_cur_cam0 : (4, 4) ndarray
        First camera pose of the current session in its (metric) map frame.
    cur_points, reference : optional
        Current cloud (map frame) and reference cloud; with both, the prior is
        checked by a fast alignment and, if that fails its health checks, the
        global multi-start registration is tried.
    scale : float, optional
        Scale of the prior; default: ratio of the median depths of the reference
        cloud seen from the reference camera and the current cloud seen from the
        first camera (1.0 without clouds: both frames are metric).
    global_fallback : bool
        Allow the multi-start fallback.

    Returns
    -------
    InitialGuess
    """
    t0 = time.perf_counter()
    have_clouds = cur_points is not None and reference is not None
    ref = as_reference(reference) if reference is not None else None
    if scale is None:
        scale = 1.0
        if have_clouds:
            d_ref = _median_depth(ref.points, np.asarray(T_ref_camref, dtype=float))
            d_cur = _median_depth(np.asarray(cur_points, dtype=float), np.asarray(T_cur_cam0, dtype=float))
            if np.isfinite(d_ref) and np.isfinite(d_cur) and d_cur > 0:
                scale = d_ref / d_cur
    prior = camera_prior(T_ref_camref, T_cur_cam0, scale=scale)
    if not have_clouds:
        return InitialGuess(
            T_ref_cur=prior, source=GuessSource.FIRST_CAMERA, fast=None, seconds=time.perf_counter() - t0
        )
    fast = fast_align(cur_points, ref, init=prior, config=config)
    # Degenerate geometry (a plane, a sphere) is not cured by other starts: they only find
    # other, equally good-looking fits (docs/alignment.md, "Initial guess and global fallback").
    only_degenerate = (
        fast.health.degenerate
        and fast.health.inlier_ratio >= config.health.min_inlier_ratio
        and fast.health.overlap >= config.health.min_overlap
    )
    # Too few current points: the multi-start has nothing to rotate either.
    too_few = len(np.asarray(cur_points).reshape(-1, 3)) < MIN_CURRENT_POINTS
    if fast.health.ok or not global_fallback or only_degenerate or too_few:
        return InitialGuess(
            T_ref_cur=fast.T_ref_cur, source=GuessSource.FIRST_CAMERA_FAST, fast=fast, seconds=time.perf_counter() - t0
        )
    glob = global_registration(cur_points, ref, config=config, around=prior)
    chosen = glob if (glob.health.ok or glob.health.inlier_ratio > fast.health.inlier_ratio) else fast
    return InitialGuess(
        T_ref_cur=chosen.T_ref_cur,
        source=GuessSource.GLOBAL if chosen is glob else GuessSource.FIRST_CAMERA_FAST,
        fast=chosen,
        seconds=time.perf_counter() - t0,
    )
