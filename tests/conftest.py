"""Session-wide test set-up."""

import signal


def pytest_configure(config):
    # A shell that starts a job in the background (``cmd &`` without job control) starts it with
    # SIGINT ignored, and Python then installs no KeyboardInterrupt handler: the Ctrl-C tests
    # (in-process and in subprocesses, which inherit the disposition) would see nothing. Restore
    # the default so that they test the tool, not how the suite was launched.
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
