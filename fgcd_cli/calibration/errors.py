"""Errors of the calibration package."""

from __future__ import annotations

from fgcd_cli.errors import AlgorithmError

__all__ = ["CalibrationError"]


class CalibrationError(AlgorithmError):
    """The samples cannot give a trustworthy calibration (degenerate motions, no board...).

    The message says what is wrong with the samples and what to do about it.
    """
