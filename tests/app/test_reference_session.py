"""The reference capture explores widely enough for its cloud's depths (fgcd_cli.app.reference_session)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fgcd_cli.app.reference_session import MAX_REFERENCE_LEG_M, _feasible_leg_m, _inside_workspace
from fgcd_cli.relocation.session import exploration_waypoints, reference_leg_m


@pytest.mark.parametrize("depth_m, fx_px, sigma_rel", [(1.55, 601.0, 0.01), (0.6, 1200.0, 0.005), (3.0, 900.0, 0.02)])
def test_the_leg_triangulates_to_the_wanted_depth_precision(depth_m, fx_px, sigma_rel):
    """Two views a leg apart, their disparity measured to the VSE's 0.5 px: the triangulated depths
    scatter by ``sigma_rel`` of the depth (the model's first-order error; 10 % for the sample of 20000)."""
    b = reference_leg_m(depth_m=depth_m, fx_px=fx_px, sigma_rel=sigma_rel)
    rng = np.random.default_rng(0)
    disparity = fx_px * b / depth_m + 0.5 * rng.standard_normal(20000)
    z = fx_px * b / disparity
    assert np.std(z) / depth_m == pytest.approx(sigma_rel, rel=0.1)
    # and a leg half as long scatters them twice as much: the rule is not satisfied by any leg
    half = fx_px * (b / 2) / (fx_px * (b / 2) / depth_m + 0.5 * rng.standard_normal(20000))
    assert np.std(half) / depth_m > 1.8 * sigma_rel


@pytest.mark.parametrize("depth_m, fx_px", [(math.nan, 600.0), (-1.0, 600.0), (1.0, 0.0), (math.inf, 600.0)])
def test_no_leg_without_a_depth(depth_m, fx_px):
    assert math.isnan(reference_leg_m(depth_m=depth_m, fx_px=fx_px, sigma_rel=0.01))


def _rig(lo, hi):
    caps = SimpleNamespace(workspace_min_m=(-1.0, -1.0, -1.0), workspace_max_m=(1.0, 1.0, 1.0))
    guard = SimpleNamespace(platform=SimpleNamespace(capabilities=lambda: caps),
                            limits=SimpleNamespace(workspace_min_m=lo, workspace_max_m=hi))
    return SimpleNamespace(guard=guard)


def test_the_leg_is_shortened_to_fit_the_workspace():
    """A box reaching 60 mm on every side of the start: the 150 mm leg asked for is shortened until every
    waypoint fits, and the legs that fit are as long as the box allows (within the 20 % shortening)."""
    home = np.eye(4)
    rig = _rig((-0.06, -0.06, -0.06), (0.06, 0.06, 0.06))
    leg = _feasible_leg_m(rig, home, 0.15, floor_m=0.02)
    assert leg is not None and leg < 0.15
    targets = [home @ W for W in exploration_waypoints(translation_m=leg)]
    assert _inside_workspace(rig.guard, targets)
    assert not _inside_workspace(rig.guard, [home @ W for W in exploration_waypoints(translation_m=leg / 0.8)])
    assert leg > 0.8 * 0.06 / 1.0 - 1e-9  # the legs reach at least 80 % of the box's half-width


def test_no_wider_leg_when_the_workspace_is_too_small():
    rig = _rig((-0.02, -0.02, -0.02), (0.02, 0.02, 0.02))
    assert _feasible_leg_m(rig, np.eye(4), 0.15, floor_m=0.055) is None


def test_the_leg_never_exceeds_the_cap():
    rig = _rig(None, None)
    assert _feasible_leg_m(rig, np.eye(4), 10.0, floor_m=0.05) == pytest.approx(MAX_REFERENCE_LEG_M)
