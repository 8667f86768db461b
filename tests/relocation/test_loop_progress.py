"""The loop is never silent for long (issue 24, item 7): a line per step and while it waits."""

import time

from fgcd_cli.relocation.config import RelocationConfig
from fgcd_cli.relocation.loop.context import LoopContext
from fgcd_cli.relocation.loop.parallel import relocate
from fgcd_cli.relocation.racr.aligner import AlignmentEstimate
from fgcd_core.sim3 import Sim3
from tests.relocation.test_loop import _exact_session, make_case


def test_every_step_and_every_wait_says_something(monkeypatch):
    X, platform, T_map_base, s, T_ref_camref, T_ref_cur, _T_ref_base = make_case(proportional=0.2)

    def slow_exact(*, serial=0, state=None, **kw):
        time.sleep(0.3)
        return [
            AlignmentEstimate(
                T_ref_cur=T_ref_cur,
                stage="fast",
                ok=True,
                reason="exact",
                vse_frame=state.frames_processed,
                seconds=0.3,
                serial=serial,
            )
        ]

    vse, session, ref = _exact_session(platform, X, T_map_base, s, T_ref_camref)
    lines: list[tuple[float, str]] = []
    progress: list[tuple[int, int, str]] = []
    session.on_event = lambda text: lines.append((time.monotonic(), text))
    session.on_progress = lambda done, total, label: progress.append((done, total, label))
    t0 = time.monotonic()
    res = relocate(
        LoopContext(
            session=session,
            reference=ref,
            ref_index=None,
            camera=None,
            scale=s,
            T_flange_cam=X,
            init=Sim3(),
            config=RelocationConfig(mode="parallel", eta=1e-4, max_adjustments=12, heartbeat_s=0.1),
            aligner=slow_exact,
        )
    )
    vse.stop()
    assert res.converged
    texts = [t for _, t in lines]
    assert any("waiting for an alignment" in t for t in texts)
    assert any("still aligning" in t for t in texts)  # the heartbeat while an alignment takes longer
    moves = [t for t in texts if ": moving" in t]
    assert len(moves) == platform.moves  # one line per motion
    assert progress and all(label.startswith("adjustment") for _, _, label in progress)
    # never the issue's ~3 s of silence, with a 0.1 s heartbeat and 0.3 s alignments (loose: a loaded machine)
    stamps = [t0] + [t for t, _ in lines]
    assert max(b - a for a, b in zip(stamps, stamps[1:])) < 3.0


def _session_with_a_fixed_cloud(n_points: int):
    """An exact VSE session whose cloud always has ``n_points`` points (below ``min_points``: nothing to align)."""
    from tests.relocation.test_loop import ExactVse, FakeCloud, FakeState

    class FixedCloudVse(ExactVse):
        def latest(self):
            state = super().latest()
            return FakeState(state.status, state.T_map_cam, state.frames_processed, FakeCloud(n_points))

    X, platform, T_map_base, s, T_ref_camref, _T_ref_cur, _T_ref_base = make_case()
    vse, session, ref = _exact_session(platform, X, T_map_base, s, T_ref_camref)
    vse.stop()
    session.vse = FixedCloudVse(platform, X, T_map_base, s)
    return session, ref, platform, X, s


def _relocate_on(session, ref, X, s, config: RelocationConfig):
    return relocate(
        LoopContext(
            session=session,
            reference=ref,
            ref_index=None,
            camera=None,
            scale=s,
            T_flange_cam=X,
            init=Sim3(),
            aligner=lambda **kw: [],
            config=config,
        )
    )


def test_a_wait_with_no_estimate_at_all_says_why():
    """The alignment thread aligns only a tracking VSE state with ``min_points`` cloud points: a heartbeat and a
    timeout that come with no estimate say what the VSE has (a statue run waited 120 s on "no estimate yet")."""
    import pytest

    from fgcd_cli.errors import AlgorithmError

    session, ref, _platform, X, s = _session_with_a_fixed_cloud(12)
    lines: list[str] = []
    session.on_event = lines.append
    with pytest.raises(
        AlgorithmError,
        match=r"no estimate yet \(the VSE is tracking, its cloud has 12 points, "
        r"alignment needs 500\)",
    ):
        _relocate_on(session, ref, X, s, RelocationConfig(mode="parallel", estimate_timeout_s=0.5, heartbeat_s=0.1))
    session.vse.stop()
    assert any("still aligning" in t and "its cloud has 12 points" in t for t in lines)


def test_a_wait_on_a_cloud_that_cannot_grow_ends_early():
    """A standing camera makes no keyframes, so a VSE cloud below ``min_points`` stays so: the loop pauses after
    ``untrusted_min_wait_s`` with that state unchanged, not after ``estimate_timeout_s`` (a statue run waited
    120 s on a tracking VSE with an empty cloud)."""
    import pytest

    from fgcd_cli.errors import AlgorithmError

    session, ref, platform, X, s = _session_with_a_fixed_cloud(0)
    patience_s = 0.3
    t0 = time.monotonic()
    with pytest.raises(AlgorithmError, match=r"no alignment possible.*its cloud has 0 points.*camera standing still"):
        _relocate_on(
            session,
            ref,
            X,
            s,
            RelocationConfig(
                mode="parallel", estimate_timeout_s=60.0, heartbeat_s=0.1, untrusted_min_wait_s=patience_s
            ),
        )
    elapsed = time.monotonic() - t0
    session.vse.stop()
    # at least the patience; far below the 60 s timeout (a heartbeat's 0.1 s checks it; loose for a loaded machine)
    assert patience_s <= elapsed < 30.0
    assert session.timing.wait_s >= patience_s
    assert platform.moves == 0
