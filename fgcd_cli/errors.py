"""The error hierarchy of fgcd. Exit codes are assigned only at the CLI boundary.

Every message is one line a person can act on.
"""

from __future__ import annotations


class FgcdError(Exception):
    """Base of every expected failure (bad input, damaged data, hardware trouble)."""

    exit_code = 1


class UserInputError(FgcdError):
    """A command-line value, file or option is wrong."""

    exit_code = 2


class CampaignError(FgcdError):
    """A campaign is missing, malformed or would be damaged by the request."""

    exit_code = 3


class DataIntegrityError(CampaignError):
    """Checksums or manifests do not match what is on disk."""

    exit_code = 4


class ImmutableDataError(CampaignError):
    """A write would overwrite data that is immutable once written (a reference)."""

    exit_code = 5


class AlgorithmError(FgcdError):
    """An algorithm could not produce a trustworthy result (reported, not guessed)."""

    exit_code = 6


class HardwareError(FgcdError):
    """A platform or camera failed; wraps ``drivers.platform.PlatformError``."""

    exit_code = 7
