"""Session-wide test set-up."""

import signal

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
