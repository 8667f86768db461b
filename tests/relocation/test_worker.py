"""relocation/loop/worker.py: the alignment thread and the waits on what it publishes."""

import time
from types import SimpleNamespace

import numpy as np

from fgcd_cli.relocation.loop.worker import AlignmentWorker


def test_the_worker_wakes_its_reader_on_publication():
    state = SimpleNamespace(status="tracking", cloud=np.zeros((10, 3)), frames_processed=0)
    vse = SimpleNamespace(latest=lambda: state)

    def aligner(*, state, serial=0, **kw):
        time.sleep(0.05)
        return [SimpleNamespace(serial=serial, ok=True, T_ref_cur=None)]

    worker = AlignmentWorker(vse=vse, problem=None, init=None, min_points=1, aligner=aligner).start()
    try:
        t0 = time.monotonic()
        assert worker.wait_until(lambda e: e is not None and e.serial == 1, 10.0)
        assert time.monotonic() - t0 < 5.0 and worker.latest().serial == 1
        assert not worker.wait_until(lambda e: e.serial == 99, 0.05)  # one frame only: no newer estimate
    finally:
        worker.stop()


def test_a_wait_for_a_3d_view_that_never_comes_is_counted_on_the_rig():
    """The platform stands still for the whole agreement wait, whether an estimate comes or not."""
    import time
    from types import SimpleNamespace

    from fgcd_cli.relocation.racr.estimates import _wait_for_view_after
    from fgcd_cli.relocation.session import SessionTiming

    class _Silent:  # an alignment thread that publishes nothing
        error = None

        def wait_until(self, predicate, timeout_s):
            time.sleep(timeout_s)
            return False

        def latest_ok(self):
            return None

    timing = SessionTiming()
    ctx = SimpleNamespace(
        config=SimpleNamespace(agreement_wait_s=0.2), session=SimpleNamespace(timing=timing), say=lambda m: None
    )
    est, note = _wait_for_view_after(ctx, _Silent(), after_frame=10)
    assert est is None and "no 3D estimate" in note
    assert timing.wait_s >= 0.2
