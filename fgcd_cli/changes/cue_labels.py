"""Relief and colour cues of a pair, and the label of each change region (relief / colour / both).

The capture's directional lightings are a photometric-stereo set
(:mod:`fgcd_cli.changes.photometric`): the reference and the registered current
stack are fitted in one basis, and two cues are compared per pixel:

* **relief**: the angle between the reference and current normals (pits, lifted
  flakes, cracks, losses change the surface orientation);
* **colour**: the log ratio of the albedos (stains, salts, fading change the
  reflectance but not the shape).

Label rule (stated, not fitted to data): each cue, smoothed like the detection
score, is turned into its empirical tail probability over the compared pixels of
the pair (the pair's own null, as in :mod:`fgcd_cli.changes.significance`). A
region's evidence for a cue is the median over its pixels of ``-log10 p``. A cue
*supports* a region when its evidence is at least 2 (the region's typical pixel
is in the pair's top 1 % for that cue). The label is ``both`` when both cues
support the region and the weaker has at least half the evidence of the stronger,
otherwise the cue with the larger evidence. A missing cue (fewer than three
directional lightings, or the fit failed) leaves the label ``None``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from fgcd_cli.changes.photometric import joint_photometric_stereo, relief_and_colour_cues
from fgcd_cli.changes.regions import ChangeRegion
from fgcd_cli.errors import AlgorithmError, UserInputError

SUPPORT_LOG10_P = 2.0
"""A cue supports a region when its typical pixel is in the pair's top 10^-2 for that cue."""

BOTH_RATIO = 0.5
"""``both`` when the weaker supporting cue has at least this share of the stronger one's evidence."""


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
    evidence: dict[int, tuple[float, float]] = field(default_factory=dict)
    """Region id -> (relief, colour) evidence, median ``-log10 p`` over the region."""


def relief_colour_cues(refs: list[np.ndarray], currents: list[np.ndarray], *, valid: np.ndarray,
                       ambient_index: int | None = 0, light_dirs: np.ndarray | None = None) -> CueMaps:
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
        return CueMaps(relief=None, colour=None, reason=f"{directional} directional lighting(s); photometric stereo needs 3")
    try:
        fit_ref, fit_cur = joint_photometric_stereo(refs, currents, valid=valid, ambient_index=ambient_index,
                                                    light_dirs=light_dirs)
    except (AlgorithmError, UserInputError, np.linalg.LinAlgError) as exc:
        return CueMaps(relief=None, colour=None, reason=f"photometric stereo failed: {exc}")
    relief, colour = relief_and_colour_cues(fit_ref, fit_cur, valid=valid)
    return CueMaps(relief=relief, colour=colour, normals_ref=fit_ref.normals, albedo_ref=fit_ref.albedo)


def _neglog10_tail(cue: np.ndarray, valid: np.ndarray, *, smooth_sigma_px: float) -> np.ndarray:
    """``-log10 P(C >= c)`` per pixel under the empirical distribution of the smoothed cue over ``valid``."""
    smooth = cv2.GaussianBlur(cue.astype(np.float32), (0, 0), smooth_sigma_px) if smooth_sigma_px > 0 else cue
    values = np.sort(smooth[valid])
    if values.size == 0:
        return np.zeros(cue.shape, np.float32)
    rank = np.searchsorted(values, smooth, side="left")
    survival = (values.size - rank + 1) / (values.size + 1)
    return (-np.log10(survival)).astype(np.float32)


def label_regions(regions: list[ChangeRegion], labels: np.ndarray, cues: CueMaps, *, valid: np.ndarray,
                  smooth_sigma_px: float) -> None:
    """Set ``region.cue`` of every region from the cue maps (the module's rule); fills ``cues.evidence``.

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
    relief_tail = _neglog10_tail(cues.relief, valid, smooth_sigma_px=smooth_sigma_px)
    colour_tail = _neglog10_tail(cues.colour, valid, smooth_sigma_px=smooth_sigma_px)
    for region in regions:
        inside = labels == region.id
        relief = float(np.median(relief_tail[inside]))
        colour = float(np.median(colour_tail[inside]))
        cues.evidence[region.id] = (relief, colour)
        strong, weak = max(relief, colour), min(relief, colour)
        if weak >= SUPPORT_LOG10_P and weak >= BOTH_RATIO * strong:
            region.cue = "both"
        else:
            region.cue = "relief" if relief >= colour else "colour"
