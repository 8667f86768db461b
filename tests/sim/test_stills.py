"""The simulated camera's stills integrate over the pixel area; its stream frames are point-sampled."""

from __future__ import annotations

import numpy as np

from fgcd_core.se3 import exp_se3
from fgcd_drivers.sim.rig import SimRigConfig, build_sim_rig
from fgcd_drivers.sim.sensor import CameraEffects

NOISELESS = CameraEffects(gamma=1.0)


def _rig(still_supersample: int):
    return build_sim_rig(
        scene="relief_panel",
        config=SimRigConfig(
            noise="none",
            intrinsics_error="none",
            seed=3,
            effects=NOISELESS,
            exposure=4.0,
            still_supersample=still_supersample,
        ),
    )


def test_still_is_the_box_filtered_supersampled_render_and_frames_stay_point_sampled():
    rig = _rig(2)
    T = rig.ground_truth.T_world_cam_true()
    intr = rig.ground_truth.intrinsics_true()
    still = rig.camera.grab_still().image
    frame = rig.camera.grab().image
    renderer = rig.world.renderer
    expected_still = (
        renderer.with_supersample(2)
        .render(T, intr, rig.lights.lighting, effects=NOISELESS, exposure=4.0, want=("gray",))
        .gray
    )
    expected_frame = renderer.render(T, intr, rig.lights.lighting, effects=NOISELESS, exposure=4.0, want=("gray",)).gray
    assert np.allclose(still, expected_still, atol=1e-6)
    assert np.allclose(frame, expected_frame, atol=1e-6)
    assert renderer.supersample == 1  # the twin did not change the world's renderer
    # the same scene either way: the images differ at edges and in fine texture, not in level
    assert abs(float(still.mean()) - float(frame.mean())) < 0.01
    assert float(np.median(np.abs(still - frame))) < 0.02


def test_a_sub_pixel_move_changes_stills_at_most_half_as_much_as_point_sampled_frames():
    # Model: a pixel straddling an edge of contrast C, seen through s x s box-filtered
    # samples, changes by at most C * ceil(delta * s) / s under a move of delta px
    # (each column of samples that crosses the edge moves 1/s of the pixel); one
    # ray per pixel flips by C. For delta = 0.3 px and s = 2 the bound is C / 2;
    # the largest changes (99.9th percentile, the edge pixels) follow it, with
    # 0.1 of margin for texture and shading.
    rig = _rig(2)
    renderer = rig.world.renderer
    intr = rig.ground_truth.intrinsics_true()
    T = rig.ground_truth.T_world_cam_true()
    depth = rig.ground_truth.depth(T)
    shift_m = 0.3 * float(np.median(depth[depth > 0])) / intr.fx  # 0.3 px at the object's median depth
    T_moved = T @ exp_se3(np.r_[shift_m, 0.0, 0.0, 0.0, 0.0, 0.0])

    def largest_change(r):
        a = r.render(T, intr, rig.lights.lighting, effects=NOISELESS, exposure=4.0, want=("gray",)).gray
        b = r.render(T_moved, intr, rig.lights.lighting, effects=NOISELESS, exposure=4.0, want=("gray",)).gray
        return float(np.percentile(np.abs(a - b), 99.9))

    point, area = largest_change(renderer), largest_change(renderer.with_supersample(2))
    assert area <= 0.6 * point
