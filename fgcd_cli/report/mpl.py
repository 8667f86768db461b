"""matplotlib as the reports use it: the Agg backend, quiet where the user's configuration folder is not writable.

Rule (README, "Errors": one line per failure): a read-only or full home makes
matplotlib log two warnings to stderr ("mkdir -p failed", "created a temporary
cache directory") and then work from a temporary folder it removes at exit; the
figures are the same, so those lines are not the user's business. Other
matplotlib errors still reach the log.
"""

from __future__ import annotations

import logging

logging.getLogger("matplotlib").setLevel(logging.ERROR)

import matplotlib  # noqa: E402 - after the logger's level

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402, F401 - the reports' tick formatters

__all__ = ["matplotlib", "plt"]
