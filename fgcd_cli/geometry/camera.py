"""The pinhole camera: re-exported from :mod:`fgcd_core.camera`, where it lives."""

from fgcd_core.camera import PinholeCamera  # noqa: F401

__all__ = ["PinholeCamera"]
