"""app/rig.py: the guard a rig's motions pass through."""

from types import SimpleNamespace

import numpy as np

from fgcd_cli.errors import run_record


def test_the_rig_guard_marks_its_motions_and_not_its_question():
    from fgcd_cli.app.rig import _recorded_guard

    asked = []

    def confirm(text):
        asked.append(run_record.moving)
        return True

    class Platform:
        name = "sim"

        def __init__(self):
            self.pose = np.eye(4)
            self.during = None

        def flange_pose(self):
            return self.pose.copy()

        def capabilities(self):
            return SimpleNamespace(
                workspace_min_m=(-1, -1, -1), workspace_max_m=(1, 1, 1), controllable=("x", "y", "z", "rx", "ry", "rz")
            )

        def move_to(self, T, speed_fraction=1.0):
            self.during = run_record.moving
            self.pose = T
            return SimpleNamespace(duration_s=0.0)

        def stop(self):
            pass

    from fgcd_core.platform import GuardLimits

    run_record.reset()
    platform = Platform()
    guard = _recorded_guard(platform, GuardLimits(), confirm)
    target = np.eye(4)
    target[0, 3] = 0.001
    guard.move_to(target)
    assert asked == [False] and platform.during is True and run_record.moving is False
    run_record.reset()
