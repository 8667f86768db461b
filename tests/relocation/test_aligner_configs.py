"""The loop's alignment options reach both stages (the paper's ablations, paper 000 §5.4)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from fgcd_cli.alignment.fast_config import FastAlignConfig, ScaleStepConfig
from fgcd_cli.alignment.reference import ReferenceIndex
from fgcd_cli.alignment.synthetic import ReliefScene
from fgcd_cli.relocation.config import ReferenceData, RelocationConfig
from fgcd_cli.relocation.loop.context import LoopContext
from fgcd_cli.relocation.racr.aligner import align_once
from fgcd_core.sim3 import Sim3

SCALE_ERROR = 1.06  # the session's map is 6 % too large: the fast stage's scale step must remove it


def _state(points_map: np.ndarray):
    cloud = SimpleNamespace(points=points_map, keyframe_ids=np.zeros(0))
    return SimpleNamespace(cloud=cloud, keyframes=[], frames_processed=1)


def _problem(config: RelocationConfig, reference: ReferenceData, index: ReferenceIndex):
    ctx = LoopContext(
        session=None,
        reference=reference,
        ref_index=index,
        camera=None,
        scale=1.0,
        T_flange_cam=np.eye(4),
        init=Sim3(),
        config=config,
    )
    return ctx.problem()


def test_the_scale_ablation_keeps_the_scale_the_default_estimates_it():
    scene = ReliefScene(seed=3)
    rng = np.random.default_rng(4)
    pts, normals, intensities = scene.sample(20000, rng=rng)
    index = ReferenceIndex(pts, normals=normals, intensities=intensities)
    reference = ReferenceData(points=pts, intensities=intensities, T_ref_camref=np.eye(4))
    cur, _, _ = scene.sample(8000, rng=rng, xlim=(-0.2, 0.15), ylim=(-0.15, 0.2))
    state = _state(cur * SCALE_ERROR)
    default = _problem(RelocationConfig(fine=False), reference, index)
    estimated = align_once(state=state, problem=default, init=Sim3())[0].T_ref_cur.scale
    no_scale = RelocationConfig(
        fine=False, fast_align=replace(FastAlignConfig(), scale=ScaleStepConfig(estimate=False))
    )
    kept = align_once(state=state, problem=_problem(no_scale, reference, index), init=Sim3())[0].T_ref_cur.scale
    # default: the scale step brings the map back to metric (within 1 %); -S: the prior's scale, exactly
    assert abs(estimated * SCALE_ERROR - 1.0) < 0.01
    assert kept == 1.0


def test_the_loop_passes_its_fine_options():
    config = RelocationConfig(fine_align=replace(RelocationConfig().fine_align, alpha=0.7, refine_keyframes=False))
    problem = _problem(
        config, ReferenceData(points=np.zeros((3, 3)), intensities=np.zeros(3), T_ref_camref=np.eye(4)), None
    )
    assert problem.fine_config.alpha == 0.7 and not problem.fine_config.refine_keyframes
