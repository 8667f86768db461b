"""Session-wide test set-up."""

import signal
from types import SimpleNamespace

import pytest
from hypothesis import settings

# Property tests check behaviour, not speed (speed belongs to `fgcd bench`): no per-example deadline, which a
# loaded 2-core machine exceeds (hypothesis' default is 200 ms).
settings.register_profile("fgcd", deadline=None)
settings.load_profile("fgcd")


def pytest_configure(config):
    # A shell that starts a job in the background (``cmd &`` without job control) starts it with
    # SIGINT ignored, and Python then installs no KeyboardInterrupt handler: the Ctrl-C tests
    # (in-process and in subprocesses, which inherit the disposition) would see nothing. Restore
    # the default so that they test the tool, not how the suite was launched.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def stand_in_rig(monkeypatch):
    """``open_rig`` replaced by a stand-in that records its options and asks the first-motion question."""
    import fgcd_cli.app.rig as rigs

    seen: dict = {}

    def open_rig(request=None, *, hooks=None, **kwargs):
        if request is not None:  # the use cases' typed form: RigRequest + RigHooks
            kwargs = {**request.__dict__, **hooks.__dict__}
        seen.update(kwargs)
        if kwargs.get("confirm") is not None:
            seen["answer"] = kwargs["confirm"](
                "First motion of this session on 'sim': move flange by (1, 0, 0) mm. Proceed?"
            )
        platform = SimpleNamespace(name="sim", stop=lambda: seen.setdefault("stopped", True))
        guard = SimpleNamespace(platform=platform, trip=lambda reason: seen.setdefault("tripped", reason))
        handles = SimpleNamespace(guard=guard)
        return rigs.OpenedRig(
            handles=handles, close=lambda: seen.setdefault("closed", True), sim=None, info={"scenario": None}
        )

    monkeypatch.setattr(rigs, "open_rig", open_rig)
    return seen


@pytest.fixture
def stand_in_relocation(monkeypatch):
    """The revisit's relocation replaced by one that converged at once and wrote visit ``visit``."""
    import fgcd_cli.app.revisit as revisit

    relocation = SimpleNamespace(
        converged=True, reason="ok", adjustments=1, wall_s=1.0, session_s=1.0, records=[], residual=None
    )
    result = SimpleNamespace(
        observation_path="visit",
        relocation=relocation,
        coarse=None,
        cloud_points=0,
        images=["front"],
        scale=SimpleNamespace(scale=1.0),
    )
    monkeypatch.setattr(revisit, "relocate_and_capture", lambda *a, **k: result)
    return result
