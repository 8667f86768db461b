"""``python -m fgcd_cli.bench.faults.child ARGS``: ``fgcd ARGS`` as a terminal would start it, for signal faults.

A bench started in the background (``nohup``, ``&``, a CI runner) hands its
children SIGINT (and SIGHUP) ignored; Python then installs no Ctrl-C handler
and fgcd keeps ``nohup``'s choice for SIGHUP (``cli/app.py``,
``stop_signals_as_interrupts``), so a SIGINT or SIGHUP fault would hit nothing.
This launcher gives the child a terminal's defaults first.
"""

from __future__ import annotations

import runpy
import signal

if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C raises KeyboardInterrupt, as on a terminal
    signal.signal(signal.SIGHUP, signal.SIG_DFL)  # a closed terminal ends the command (fgcd turns it into a stop)
    runpy.run_module("fgcd_cli.cli.app", run_name="__main__", alter_sys=True)  # the fgcd command itself
