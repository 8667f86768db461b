"""Weak-direction probe: does the alignment pull a perturbation along a weak direction back?

The conditioning check (:func:`fgcd_cli.alignment.health.similarity_conditioning`)
uses smoothed normals, which call a shallow relief, mortar joints or an
object's outline flat. The probe is a finite-size test of the actual
point-to-plane problem instead (docs/alignment.md, "Health").
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.alignment.icp_levels import LevelInputs, finest, run_levels
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_core.se3 import exp_se3
from fgcd_core.sim3 import Sim3

__all__ = ["probe_weak_directions"]


def _perturbation(direction: np.ndarray, centre: np.ndarray, radius: float) -> Sim3:
    """Similarity (reference frame) of a 7-vector in the normalised parameters of
    :func:`~fgcd_cli.alignment.health.similarity_conditioning`: translation ``radius * v[:3]``,
    rotation ``v[3:6]`` and log-scale ``v[6]`` about ``centre``."""
    R = exp_se3(np.r_[0.0, 0.0, 0.0, direction[3:6]])[:3, :3]
    s = math.exp(float(direction[6]))
    return Sim3(R, centre + radius * direction[:3] - s * (R @ centre), s)


def probe_weak_directions(
    T: Sim3,
    cur_points: np.ndarray,
    ref: ReferenceIndex,
    *,
    points: np.ndarray,
    directions: np.ndarray,
    config: FastAlignConfig = FastAlignConfig(),
) -> tuple[float, ...]:
    """How much of a perturbation along each weak direction the alignment recovers.

    The result ``T`` is moved along each direction (alternating signs) by a
    similarity that displaces ``points`` by ``probe.rel`` of the reference
    width (RMS; at least 3 times its roughness), and the last ICP level runs
    again from there (``probe.points`` points, ``probe.iterations``
    iterations). A direction pinned by the data (a relief, joints, the object's
    sides) pulls the estimate back; a free one (in-plane on a plane, rotation
    on a sphere) leaves it where it was put. (Written here: no registration
    library offers a degeneracy test of this kind.)

    Parameters
    ----------
    T : Sim3
        The alignment result ``T_ref_cur``.
    cur_points : (N, 3) ndarray
        Current cloud (its map frame).
    ref : ReferenceIndex
    points : (K, 3) ndarray
        Reference points matched by the result (metres), defining the
        normalisation of ``directions``.
    directions : (7, D) ndarray
        Unit vectors in the parameters ``(tx, ty, tz, rx, ry, rz, log s)`` of
        :func:`~fgcd_cli.alignment.health.similarity_conditioning`
        (translation in units of the RMS radius of ``points`` about their centroid).
    config : FastAlignConfig

    Returns
    -------
    tuple of float
        Per direction, the RMS displacement of ``points`` between the rerun's
        result and ``T``, over the perturbation's (0: fully recovered).
    """
    q = np.asarray(points, dtype=float)
    c = q.mean(axis=0)
    L = float(np.sqrt(np.mean(np.sum((q - c) ** 2, axis=1))))
    if L <= 0 or directions.size == 0:
        return ()
    if len(q) > 2000:
        q = q[:: len(q) // 2000 + 1]
    size = max(config.probe.rel * ref.width, 3.0 * ref.roughness)
    levels = config.levels
    probe_config = replace(
        config,
        levels=replace(
            levels,
            points=levels.points[:-1] + (config.probe.points,),
            iterations=levels.iterations[:-1] + (config.probe.iterations,),
        ),
    )
    order = np.random.default_rng(config.seed + 1).permutation(len(cur_points))
    inputs = LevelInputs(cur=cur_points, weights=None, ref=ref, order=order)
    out = []
    for k in range(directions.shape[1]):
        v = directions[:, k]
        unit = _perturbation(v, c, L)
        disp = float(np.sqrt(np.mean(np.sum((unit.apply(q) - q) ** 2, axis=1))))
        if disp <= 0:
            out.append(0.0)
            continue
        amount = (size / disp) * (1.0 if k % 2 == 0 else -1.0)
        start = _perturbation(v * amount, c, L) @ T
        # Correspondences on the reference cloud's view rim are left out: there the
        # point-to-plane residuals of a curved cloud pull a perturbation back although the
        # rim is only where the camera stopped seeing. The object's own outline stays: it
        # pins a stele's height (docs/alignment.md, "Health").
        T_back = run_levels(
            inputs, start, finest(config), probe_config, estimate_scale=config.scale.estimate, ignore_ref=ref.view_rim
        ).T
        if T_back is None:
            out.append(math.inf)
            continue
        correction = T_back @ T.inverse()
        out.append(float(np.sqrt(np.mean(np.sum((correction.apply(q) - q) ** 2, axis=1)))) / size)
    return tuple(out)
