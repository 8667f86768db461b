"""Placeholder of a fault group of ``fgcd bench faults`` (being written)."""

from __future__ import annotations

__all__ = ["FAULTS", "PER_CLASS_FULL", "inject"]

FAULTS: tuple[str, ...] = ()
PER_CLASS_FULL = 1


def inject(fault, seed, campaign):
    """Run one fault of this group."""
    raise ValueError(f"unknown fault '{fault}'")
