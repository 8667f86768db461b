"""The options of a diff (``fgcd diff``): their one check, the campaign diff's edge check, the stored-diff guard.

:func:`check_diff_options` runs when a request is made, before anything is read or
written; :data:`EDGE_CHECK_PX` is the one default edge check of every diff;
:func:`check_stored_diff` refuses to replace a visit's stored diff made with other
options (docs/change-detection.md, "Commands"). The use cases themselves are in :mod:`fgcd_cli.app.diff`.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from fgcd_cli.archive.freshness import AnalysisOptions, stored_options
from fgcd_cli.campaign import schema
from fgcd_cli.changes.config import MIN_REGION_CONTRAST
from fgcd_cli.errors import ImmutableDataError, UserInputError


def check_diff_options(
    *,
    mm_per_px: float | None,
    edge_check_px: int | None,
    ambient_index: int | None = None,
    min_contrast: float | None = None,
    files: dict[str, Path | None] | None = None,
) -> None:
    """The one check of a diff's options, run when a request is made: before anything is read or written.

    Raises :class:`UserInputError` (exit 2) for a scale that is not a positive finite
    number of mm per px (a negative or zero scale would give non-physical areas), an
    edge check outside 0..8 px, a negative ambient index, a contrast floor outside [0, 1), or a named
    file that is not there.
    """
    if mm_per_px is not None and (
        isinstance(mm_per_px, bool)
        or not isinstance(mm_per_px, (int, float))
        or not math.isfinite(mm_per_px)
        or mm_per_px <= 0
    ):
        raise UserInputError(f"--mm-per-px must be a positive number of millimetres per pixel, got {mm_per_px}")
    if edge_check_px is not None:
        checked_edge_check_px(edge_check_px)
    if min_contrast is not None and (
        isinstance(min_contrast, bool) or not isinstance(min_contrast, (int, float)) or not 0.0 <= min_contrast < 1.0
    ):
        raise UserInputError(f"--min-contrast must be a fraction from 0 (report all) to below 1, got {min_contrast}")
    if ambient_index is not None and ambient_index < 0:
        raise UserInputError(f"--ambient-index must be 0 or more, got {ambient_index}")
    for option, path in (files or {}).items():
        if path is not None and not Path(path).is_file():
            raise UserInputError(f"{option}: file not found: {path}")


# A relocated visit is never at the reference pose to the pixel: parallax, occlusion
# and resampling differences at strong edges remain that the flat registration
# cannot absorb. Every diff (a campaign's or two sets of image files, which come
# from a revisit too) sets aside regions that lie along strong reference edges and
# that a shift of up to this many pixels explains (region-level edge check,
# docs/change-detection.md, "Change detection pipeline", step 8); they stay visible in the report.
EDGE_CHECK_PX = 2


def default_edge_check_px(px: int | None) -> int:
    """The edge check of a diff: ``px`` when given, else :data:`EDGE_CHECK_PX` (the one default)."""
    return EDGE_CHECK_PX if px is None else px


def checked_edge_check_px(px: int) -> int:
    """The edge check shift ``px`` as an int, once checked.

    Raises
    ------
    UserInputError
        ``px`` is outside 0 (off) .. 8 px.
    """
    if not 0 <= px <= 8:
        raise UserInputError(f"--edge-check must be between 0 (off) and 8 px, got {px}")
    return int(px)


def contrast_options(min_contrast: float | None) -> dict:
    """The detector option a diff's ``--min-contrast`` gives (none when not given: the detector's default)."""
    return {} if min_contrast is None else {"min_contrast": float(min_contrast)}


def _effective(options: AnalysisOptions) -> AnalysisOptions:
    """``options`` with the defaults spelled out (``None`` and 2 px make the same diff; so do ``None`` and
    the detector's contrast floor)."""
    return dataclasses.replace(
        options,
        edge_check_px=default_edge_check_px(options.edge_check_px),
        min_contrast=MIN_REGION_CONTRAST if options.min_contrast is None else float(options.min_contrast),
    )


def options_text(options: AnalysisOptions) -> str:
    """``--mm-per-px 0.5, --edge-check 2`` (the options as a person would give them)."""
    o = _effective(options)
    parts = [
        f"--mm-per-px {o.mm_per_px}" if o.mm_per_px is not None else "no --mm-per-px",
        f"--edge-check {o.edge_check_px}",
        f"--min-contrast {o.min_contrast:g}",
    ]
    parts += ["--no-register"] if not o.register else []
    parts += ["--no-geometry"] if not o.geometry else []
    parts += [f"--roi sha256 {o.eval_mask_sha256[:12]}"] if o.eval_mask_sha256 else []
    return ", ".join(parts)


def check_stored_diff(observation, options: AnalysisOptions, *, force: bool) -> str | None:
    """Refuse to replace a visit's stored diff made with other options unless forced (docs/change-detection.md, "Commands").

    Returns a warning when the stored diff's options were not recorded (an older
    fgcd): it is replaced, and the result says so. Raises
    :class:`ImmutableDataError` (exit 5) naming both sets of options otherwise.
    """
    if not observation.has(schema.change_relpath(schema.REGIONS_JSON)):
        return None
    stored = stored_options(observation)
    if stored is None:
        return (
            f"replaced the stored diff of visit {observation.name}, made by an older fgcd "
            "that did not record its options"
        )
    if force or _effective(stored) == _effective(options):
        return None
    raise ImmutableDataError(
        f"visit {observation.name} already has a diff made with {options_text(stored)}; "
        f"this one asks for {options_text(options)}: give --force to replace it"
    )
