"""``python -m fgcd_cli.bench.faults.wired_launch ARGS``: ``fgcd ARGS`` on a simulated rig whose platform is a real driver.

Bench-only test harness of ``fgcd bench faults`` (like :mod:`fgcd_cli.bench.faults.launch`):
``FGCD_BENCH_WIRED=grbl:/dev/pts/N`` (the GRBL pty emulator, a 3-DoF rig) or
``ur:127.0.0.1`` (the fake UR controller) puts the real driver behind the
simulated rig's MotionGuard (:mod:`fgcd_cli.bench.faults.wired_rig`);
``FGCD_BENCH_WIRED_LOG`` names a file that gets one line per motion.
"""

from __future__ import annotations

if __name__ == "__main__":
    import runpy

    from fgcd_cli.bench.faults.wired_rig import install_from_environment

    install_from_environment()
    runpy.run_module("fgcd_cli.cli.app", run_name="__main__", alter_sys=True)  # the fgcd command itself
