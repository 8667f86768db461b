"""The wired rig of the fault bench: the simulated camera on a real driver, frames tied at connect, faults drawn."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from fgcd_cli.bench.faults.wired import FAULTS, MOTIONS, draw_plan
from fgcd_cli.bench.faults.wired_rig import FrameMap, WiredPlatform, inner_workspace, parse_target
from fgcd_core.platform import Capabilities, MoveResult, PlatformConnectionError
from fgcd_core.se3 import exp_se3, invert_pose

pytestmark = pytest.mark.timeout(120)


def _pose(rng: np.random.Generator, *, mm: float = 300.0) -> np.ndarray:
    return exp_se3(np.r_[rng.uniform(-mm, mm, 3) / 1000.0, rng.normal(0, 1.0, 3)])


def test_frame_map_puts_the_driver_home_at_the_sim_home_and_inverts():
    rng = np.random.default_rng(3)
    T_sim_home, T_drv_home = _pose(rng), _pose(rng)
    fmap = FrameMap.at_connect(T_sim_home, T_drv_home)
    np.testing.assert_allclose(fmap.to_sim(T_drv_home), T_sim_home, atol=1e-12)
    for _ in range(5):
        T = _pose(rng)
        np.testing.assert_allclose(fmap.to_driver(fmap.to_sim(T)), T, atol=1e-12)
        np.testing.assert_allclose(fmap.to_sim(fmap.to_driver(T)), T, atol=1e-12)


def test_frame_map_keeps_motions_rigid():
    """A driver motion of d mm is a simulated motion of d mm (rotated), and a flange-frame delta is unchanged."""
    rng = np.random.default_rng(4)
    fmap = FrameMap.at_connect(_pose(rng), _pose(rng))
    A, B = _pose(rng), _pose(rng)
    dist = np.linalg.norm(B[:3, 3] - A[:3, 3])
    np.testing.assert_allclose(np.linalg.norm(fmap.to_sim(B)[:3, 3] - fmap.to_sim(A)[:3, 3]), dist, rtol=1e-12)
    np.testing.assert_allclose(invert_pose(fmap.to_sim(A)) @ fmap.to_sim(B), invert_pose(A) @ B, atol=1e-12)


def test_inner_workspace_is_inside_the_driver_box_for_any_rotation():
    rng = np.random.default_rng(5)
    caps = Capabilities(
        dof=3,
        controllable=("x", "y", "z"),
        workspace_min_m=(-0.4, -0.4, -0.4),
        workspace_max_m=(0.0, 0.0, 0.0),
        max_linear_speed_m_s=0.02,
        max_angular_speed_rad_s=0.0,
    )
    T_drv_home = np.eye(4)
    T_drv_home[:3, 3] = [-0.2, -0.15, -0.25]
    for _ in range(10):
        T_sim_home = _pose(rng)
        lo, hi = inner_workspace(caps, T_drv_home, T_sim_home, T_sim_home[:3, 3] - 1, T_sim_home[:3, 3] + 1)
        fmap = FrameMap.at_connect(T_sim_home, T_drv_home)
        for corner in range(8):
            T = T_sim_home.copy()
            T[:3, 3] = [hi[i] if (corner >> i) & 1 else lo[i] for i in range(3)]
            p = fmap.to_driver(T)[:3, 3]
            assert np.all(p >= np.array(caps.workspace_min_m) - 1e-12)
            assert np.all(p <= np.array(caps.workspace_max_m) + 1e-12)
        # the nearest face is 0.15 m away: the cube's half-size is 0.15 / sqrt(3)
        np.testing.assert_allclose(hi - lo, 2 * 0.15 / math.sqrt(3), rtol=1e-12)


@dataclass
class _Clock:
    t: float = 0.0

    def advance(self, dt: float) -> None:
        self.t += dt


class _Sim:
    """What the wired platform takes of the simulated platform: home, workspace, clock, name."""

    name = "sim"

    def __init__(self, T_home: np.ndarray) -> None:
        self.T_base_flange_home = T_home
        self.clock = _Clock()

    def true_flange_pose(self) -> np.ndarray:
        return self.T_base_flange_home.copy()

    def capabilities(self) -> Capabilities:
        h = self.T_base_flange_home[:3, 3]
        return Capabilities(
            dof=6,
            controllable=("x", "y", "z", "rx", "ry", "rz"),
            workspace_min_m=tuple(h - 0.25),
            workspace_max_m=tuple(h + 0.25),
            max_linear_speed_m_s=0.0067,
            max_angular_speed_rad_s=0.1,
        )


class _Driver:
    """A driver that arrives 1 mm off in x (its report is not its command), and can lose its link."""

    name = "stub"

    def __init__(self, T_home: np.ndarray) -> None:
        self.T = T_home.copy()
        self.lost = False

    def connect(self) -> None:
        pass

    def flange_pose(self) -> np.ndarray:
        if self.lost:
            raise PlatformConnectionError("link lost")
        return self.T.copy()

    def capabilities(self) -> Capabilities:
        return Capabilities(
            dof=6,
            controllable=("x", "y", "z", "rx", "ry", "rz"),
            workspace_min_m=(-1, -1, -1),
            workspace_max_m=(1, 1, 1),
            max_linear_speed_m_s=0.02,
            max_angular_speed_rad_s=0.5,
        )

    def move_to(self, T, *, speed_fraction: float = 1.0) -> MoveResult:
        self.T = np.asarray(T, float).copy()
        self.T[0, 3] += 0.001
        return MoveResult(
            T_base_flange_target=T, T_base_flange_reached=self.T.copy(), T_base_flange_commanded=T, duration_s=0.5
        )


def test_wired_platform_renders_at_the_reported_pose_not_the_commanded_one():
    rng = np.random.default_rng(6)
    sim, driver = _Sim(_pose(rng)), _Driver(_pose(rng))
    wired = WiredPlatform(sim, driver)
    np.testing.assert_allclose(wired.true_flange_pose(), sim.T_base_flange_home)  # before connect: the home
    wired.connect()
    np.testing.assert_allclose(wired.flange_pose(), sim.T_base_flange_home, atol=1e-12)
    target = sim.T_base_flange_home @ exp_se3(np.r_[0.004, -0.002, 0.003, 0.01, 0.0, -0.02])
    result = wired.move_to(target)
    reported = wired.map.to_sim(driver.T)
    np.testing.assert_allclose(result.T_base_flange_reached, reported, atol=1e-12)
    np.testing.assert_allclose(wired.true_flange_pose(), reported, atol=1e-12)
    assert np.linalg.norm(wired.true_flange_pose()[:3, 3] - target[:3, 3]) == pytest.approx(0.001, rel=1e-9)
    np.testing.assert_allclose(result.T_base_flange_target, target)
    assert sim.clock.t == pytest.approx(0.5)
    driver.lost = True  # the camera stays where the driver last reported it
    np.testing.assert_allclose(wired.true_flange_pose(), reported, atol=1e-12)


def test_wired_platform_moves_the_grbl_emulator_by_the_simulated_step():
    """Through the real GRBL driver: the emulator's own MPos travels the simulated step, rotated into its frame."""
    from fgcd_cli.bench.faults.wired_rig import open_driver
    from fgcd_drivers.testing.grbl_emulator import GrblEmulator

    rng = np.random.default_rng(7)
    with GrblEmulator(max_travel_mm=400.0, start_mm=[-200.0] * 3) as emu:
        T_home = _pose(rng)
        sim = _Sim(T_home)
        wired = WiredPlatform(sim, open_driver("grbl", emu.port))
        wired.connect()
        try:
            step = np.array([0.003, -0.002, 0.001])
            target = T_home.copy()
            target[:3, 3] += step
            result = wired.move_to(target)
            moved = np.array(emu.position()) - (-200.0)
            assert np.linalg.norm(moved) == pytest.approx(np.linalg.norm(step) * 1000.0, abs=0.01)
            np.testing.assert_allclose(T_home[:3, :3].T @ step * 1000.0, moved, atol=0.01)
            np.testing.assert_allclose(result.T_base_flange_reached[:3, 3], target[:3, 3], atol=1e-5)
            np.testing.assert_allclose(wired.true_flange_pose()[:3, 3], target[:3, 3], atol=1e-5)
            lo, hi = np.array(wired.capabilities().workspace_min_m), np.array(wired.capabilities().workspace_max_m)
            assert np.all(lo < T_home[:3, 3]) and np.all(T_home[:3, 3] < hi)
        finally:
            wired.close()


def test_plans_are_drawn_from_the_seed_inside_the_revisit():
    for fault in FAULTS:
        a, b = draw_plan(fault, 1003), draw_plan(fault, 1003)
        assert a == b
        assert a.phase in MOTIONS and 0 <= a.motion < MOTIONS[a.phase]
    assert len({(p.phase, p.motion, p.delay_s) for p in (draw_plan(FAULTS[0], s) for s in range(10))}) == 10


def test_target_names_a_driver_and_an_address():
    assert parse_target("grbl:/dev/pts/4") == ("grbl", "/dev/pts/4")
    assert parse_target("ur:127.0.0.1") == ("ur", "127.0.0.1")
    with pytest.raises(ValueError):
        parse_target("sim:x")


@pytest.mark.slow
def test_a_grbl_alarm_in_a_wired_revisit_stops_it_in_one_line(tmp_path):
    """One seeded fault of a class through the real driver: exit 7, one line, nothing moving, campaign intact."""
    from fgcd_cli.bench.faults.campaign_faults import prepare_campaign
    from fgcd_cli.bench.faults.wired import inject

    campaign = prepare_campaign(tmp_path)
    outcome = inject("relocate_grbl_alarm", 0, campaign)
    assert outcome.ok, outcome.to_dict()
