"""Relief and colour cues of a pair, and the label of each change region (relief / colour / both).

The capture's directional lightings are a photometric-stereo set
(:mod:`fgcd_cli.changes.photometric.stereo`): the reference and the registered current
stack are fitted in one basis, and two cues are compared per pixel:

* **relief**: the angle between the reference and current normals (pits, lifted
  flakes, cracks, losses change the surface orientation);
* **colour**: the log ratio of the albedos (stains, salts, fading change the
  reflectance but not the shape).

Label rule (stated, not fitted to data). Both cues are first put in one unit,
the relative change of a pixel's intensity they cause under the capture's lights:

* colour: an albedo log ratio ``r`` scales every lighting by ``e^r``, a relative
  change ``|r|``; the cue (a sum over channels) is divided by the number of channels;
* relief: tilting a camera-facing normal by ``theta`` towards or away from a light
  tilted ``tau`` from the optical axis changes ``n . l`` by a relative
  ``~ theta tan(tau)`` (first order, the most affected lighting); ``tau`` is the
  median tilt of the lights: the 45 degree convention of the uncalibrated fit
  (:mod:`fgcd_cli.changes.photometric.stereo`, ``tan tau = 1``), the given lights' when calibrated.

Each cue, smoothed like the detection score, gives a region two numbers:

* its *magnitude*: the median over the region of the smoothed cue, in that unit,
  less the cue's median over the compared pixels (the pair's unchanged level);
* its *evidence*: the median over the region of ``-log10 p``, ``p`` the empirical
  tail probability of the smoothed cue over the compared pixels (the pair's own
  null, as in :mod:`fgcd_cli.changes.significance`). A cue *supports* a region
  when its evidence is at least 2 (the region's typical pixel is in the pair's
  top 1 % for that cue): a cue within the pair's noise never names a change.

The label is ``both`` when both cues support the region and the weaker magnitude
is at least half the stronger, otherwise the cue with the larger magnitude. The
evidence alone cannot rank the cues: a region that is the pair's only change
holds the top pixels of *both* cues (a pit leaks a ~1 % albedo misfit into the
colour cue, tens of times below a stain's but still the pair's highest), so both
evidences reach the same ceiling ``~log10(2 N / area)`` and, compared by
evidence, every such region would be ``both``. A missing cue (fewer than three
directional lightings, or the fit failed) leaves the label ``None``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from fgcd_cli.changes.photometric.stereo import joint_photometric_stereo, relief_and_colour_cues
from fgcd_cli.changes.regions import ChangeRegion, CueLabel
from fgcd_cli.errors import AlgorithmError, UserInputError

SUPPORT_LOG10_P = 2.0
"""A cue supports a region when its typical pixel is in the pair's top 10^-2 for that cue."""

BOTH_RATIO = 0.5
"""``both`` when the weaker supporting cue has at least this share of the stronger one's magnitude."""

CONVENTIONAL_TILT_DEG = 45.0
"""Light tilt from the optical axis assumed when the lights are not given (the uncalibrated
fit's convention, :data:`fgcd_cli.changes.photometric.basis.LIGHT_TILT_DEG`)."""


@dataclass(kw_only=True)
class CueMaps:
    """Result of :func:`relief_colour_cues`."""

    relief: np.ndarray | None
    """HxW float32, angle between reference and current normals (radians); None when not computed."""
    colour: np.ndarray | None
    """HxW float32, summed absolute log albedo ratio over channels (dimensionless)."""
    normals_ref: np.ndarray | None = None
    """HxWx3 float32, reference (pseudo-)normals in the camera frame (NaN where unknown)."""
    albedo_ref: np.ndarray | None = None
    """HxW or HxWx3 float32, reference albedo (arbitrary unit when uncalibrated)."""
    reason: str = ""
    """Why the cues are missing, when they are."""
    relief_scale: float = 1.0
    """Relative intensity change per radian of normal tilt: ``tan`` of the lights' median tilt."""
    channels: int = 1
    """Channels summed in ``colour`` (3 for colour stacks)."""
    evidence: dict[int, tuple[float, float]] = field(default_factory=dict)
    """Region id -> (relief, colour) evidence, median ``-log10 p`` over the region (support)."""
    magnitude: dict[int, tuple[float, float]] = field(default_factory=dict)
    """Region id -> (relief, colour) magnitude: the region's median relative intensity change
    caused by each cue, less the pair's median (the quantity the label compares)."""


def relief_colour_cues(
    refs: list[np.ndarray],
    currents: list[np.ndarray],
    *,
    valid: np.ndarray,
    ambient_index: int | None = 0,
    light_dirs: np.ndarray | None = None,
) -> CueMaps:
    """Relief and colour cue maps of a registered pair (photometric stereo of both stacks in one basis).

    Parameters
    ----------
    refs, currents : lists of K ndarrays, HxW or HxWx3 float32 in [0, 1]
        Reference stack and current stack in the reference frame, same lightings.
    valid : ndarray, HxW bool
        Compared pixels.
    ambient_index : int or None
        Index of the ambient (non-directional) lighting, left out of the fit.
    light_dirs : ndarray, Kx3, optional
        Known light directions (camera frame), calibrated fit; None: uncalibrated.

    Returns
    -------
    CueMaps
        With ``relief`` / ``colour`` None (and a reason) when fewer than three
        directional lightings are given or the fit fails.
    """
    directional = len(refs) - (ambient_index is not None)
    if directional < 3:
        return CueMaps(
            relief=None, colour=None, reason=f"{directional} directional lighting(s); photometric stereo needs 3"
        )
    try:
        fit_ref, fit_cur = joint_photometric_stereo(
            refs, currents, valid=valid, ambient_index=ambient_index, light_dirs=light_dirs
        )
    except (AlgorithmError, UserInputError, np.linalg.LinAlgError) as exc:
        return CueMaps(relief=None, colour=None, reason=f"photometric stereo failed: {exc}")
    relief, colour = relief_and_colour_cues(fit_ref, fit_cur, valid=valid)
    return CueMaps(
        relief=relief,
        colour=colour,
        normals_ref=fit_ref.normals,
        albedo_ref=fit_ref.albedo,
        relief_scale=_relief_scale(light_dirs, fit_ref.used),
        channels=fit_ref.albedo.shape[2] if fit_ref.albedo.ndim == 3 else 1,
    )


def _relief_scale(light_dirs: np.ndarray | None, used: np.ndarray) -> float:
    """``tan`` of the median tilt of the directional lights from the optical axis (module rule)."""
    if light_dirs is None:
        return float(np.tan(np.radians(CONVENTIONAL_TILT_DEG)))
    rows = np.asarray(light_dirs, np.float64)[used]
    tilt = np.arctan2(np.hypot(rows[:, 0], rows[:, 1]), -rows[:, 2])
    # Grazing lights (tan -> infinity) would make every relief change dominate: the first-order
    # relation stops holding well before; 80 degrees bounds the scale at ~5.7.
    return float(np.tan(min(float(np.median(tilt)), np.radians(80.0))))


def _smoothed(cue: np.ndarray, smooth_sigma_px: float) -> np.ndarray:
    cue = cue.astype(np.float32)
    return cv2.GaussianBlur(cue, (0, 0), smooth_sigma_px) if smooth_sigma_px > 0 else cue


def _neglog10_tail(smooth: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``-log10 P(C >= c)`` per pixel under the empirical distribution of the smoothed cue over ``valid``."""
    values = np.sort(smooth[valid])
    if values.size == 0:
        return np.zeros(smooth.shape, np.float32)
    rank = np.searchsorted(values, smooth, side="left")
    survival = (values.size - rank + 1) / (values.size + 1)
    return (-np.log10(survival)).astype(np.float32)


def label_regions(
    regions: list[ChangeRegion], labels: np.ndarray, cues: CueMaps, *, valid: np.ndarray, smooth_sigma_px: float
) -> None:
    """Set ``region.cue`` of every region from the cue maps (the module's rule).

    Fills ``cues.evidence`` and ``cues.magnitude``.

    Parameters
    ----------
    regions : list of ChangeRegion, modified in place
    labels : ndarray, HxW int32, region id per pixel
    cues : CueMaps
    valid : ndarray, HxW bool, the compared pixels (the cues' null population)
    smooth_sigma_px : float, the smoothing of the detection score, pixels
    """
    if cues.relief is None or cues.colour is None or not regions:
        return
    # Both cues as relative intensity changes (module docstring).
    relief_map = _smoothed(cues.relief, smooth_sigma_px) * np.float32(cues.relief_scale)
    colour_map = _smoothed(cues.colour, smooth_sigma_px) / np.float32(max(cues.channels, 1))
    relief_tail = _neglog10_tail(relief_map, valid)
    colour_tail = _neglog10_tail(colour_map, valid)
    relief_level = float(np.median(relief_map[valid])) if valid.any() else 0.0
    colour_level = float(np.median(colour_map[valid])) if valid.any() else 0.0
    for region in regions:
        inside = labels == region.id
        evidence = (float(np.median(relief_tail[inside])), float(np.median(colour_tail[inside])))
        relief = float(np.median(relief_map[inside])) - relief_level
        colour = float(np.median(colour_map[inside])) - colour_level
        cues.evidence[region.id] = evidence
        cues.magnitude[region.id] = (relief, colour)
        strong, weak = max(relief, colour), min(relief, colour)
        if min(evidence) >= SUPPORT_LOG10_P and weak >= BOTH_RATIO * strong:
            region.cue = CueLabel.BOTH
        else:
            region.cue = CueLabel.RELIEF if relief >= colour else CueLabel.COLOUR
