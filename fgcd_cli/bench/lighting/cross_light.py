"""Paper 000's Table 1 protocol: how far a registration across lightings lands from one made under a single light.

Within one FGCD observation the camera does not move between its lightings, so
the transform from the second observation to the first is the same for every
lighting. The median of the same-lighting homographies is the *consensus*; a
cross-lighting pair (the reference under one light, the revisit under another)
is scored by the mean distance of its homography's image corners from the
consensus's (docs/benchmarks.md, "Registration across lightings").
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from fgcd_cli.changes.registration import ransac_homography, register_to_reference
from fgcd_cli.errors import FgcdError
from fgcd_cli.metrics.afd import FdfConfig, compute_fdf
from fgcd_cli.relocation.image.refine import ImageRefineConfig, local_contrast
from fgcd_core.imaging import match_sift, to_gray_f32, to_gray_u8

__all__ = [
    "MIN_INLIERS",
    "Matcher",
    "RANSAC_PX",
    "PairMatch",
    "MIN_CONSENSUS",
    "consensus_homography",
    "same_lighting_consensus",
    "corner_error_px",
    "match_pair",
    "score_pairs",
    "summarise",
]

#: A registration with fewer RANSAC inliers than this has failed (the issue's protocol: < 8 inliers).
MIN_INLIERS = 8
#: Same-lighting registrations a consensus needs (of an FGCD group's 7).
MIN_CONSENSUS = 3
#: RANSAC reprojection threshold, pixels (the project's homography registration, ``changes/registration.py``).
RANSAC_PX = 3.0


class Matcher(StrEnum):
    """The correspondences the project registers images with, each measured by the bench."""

    SIFT = "sift"
    """SIFT on the grey image, ratio test: the ACR baseline, and the start of ``fgcd diff``'s registration."""
    DIFF = "diff"
    """``fgcd diff``'s registration (``changes/registration.py: register_to_reference``): the SIFT
    homography refined by ECC on gradient magnitude, or ECC from no motion below 15 SIFT inliers;
    a registration it refuses (overlap, correlation) fails."""
    IMAGE_STAGE = "image_stage"
    """SIFT on locally equalised images (``relocation/image/refine.py: local_contrast``): the
    relocation's final image stage, with its own ratio and feature count."""
    GRID = "grid"
    """Phase correlation of gradient-orientation patches on a grid from the whole image's ECC motion: ``fgcd afd``'s
    lighting-robust variant, the image stage's fallback, with the stage's grid."""


@dataclass(frozen=True, kw_only=True)
class PairMatch:
    """One registration of a current image onto a reference image.

    Attributes
    ----------
    matches : int
        SIFT matches passing the ratio test.
    inliers : int
        RANSAC inliers of the homography (0 when none was found).
    H_cur_ref : (3, 3) ndarray or None
        Homography mapping reference pixels ``(x, y, 1)`` to current ones; None when failed.
    """

    matches: int
    inliers: int
    H_cur_ref: np.ndarray | None
    refused: bool | None = None
    """For a registration that judges itself (``diff``): whether it refused; None: judged by inliers."""

    @property
    def failed(self) -> bool:
        """True when no homography was found, the registration refused, or (judged by inliers) it has
        fewer than :data:`MIN_INLIERS`."""
        if self.H_cur_ref is None:
            return True
        return self.refused if self.refused is not None else self.inliers < MIN_INLIERS


def _correspondences(reference: np.ndarray, current: np.ndarray, matcher: Matcher) -> tuple[np.ndarray, np.ndarray]:
    """Matched pixels ``(x, y)`` of the pair by ``matcher``, (N, 2) each (empty when it finds none)."""
    stage = ImageRefineConfig()
    if matcher == Matcher.SIFT:
        return match_sift(to_gray_u8(reference), to_gray_u8(current))
    ref, cur = to_gray_f32(reference), to_gray_f32(current)
    if matcher == Matcher.IMAGE_STAGE:
        return match_sift(
            to_gray_u8(local_contrast(ref)),
            to_gray_u8(local_contrast(cur)),
            ratio=stage.ratio,
            max_features=stage.max_features,
        )
    grid = FdfConfig(method="grid", grid_cells=stage.grid_cells, patch_px=stage.grid_patch_px, ransac_px=RANSAC_PX)
    try:
        fdf = compute_fdf(ref, cur, config=grid)
    except FgcdError:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return fdf.points_ref, fdf.points_cur


def match_pair(reference: np.ndarray, current: np.ndarray, matcher: Matcher = Matcher.SIFT) -> PairMatch:
    """Register ``current`` onto ``reference``: ``matcher``'s correspondences, a RANSAC homography at 3 px.

    Parameters
    ----------
    reference, current : (H, W) or (H, W, 3) ndarray
        Images (uint8, or floats in [0, 1]).
    matcher : Matcher
    """
    if Matcher(matcher) == Matcher.DIFF:
        reg = register_to_reference(to_gray_f32(reference), to_gray_f32(current))
        return PairMatch(
            matches=reg.sift_inliers, inliers=reg.sift_inliers, H_cur_ref=reg.H_cur_ref, refused=not reg.ok
        )
    pts_ref, pts_cur = _correspondences(reference, current, Matcher(matcher))
    H, inl = ransac_homography(pts_ref, pts_cur, ransac_px=RANSAC_PX)
    return PairMatch(matches=len(pts_ref), inliers=int(inl.sum()), H_cur_ref=H)


def score_pairs(kind: str, name: str, pairs, H_consensus: np.ndarray, *, matchers=tuple(Matcher)) -> list[dict]:
    """One row per cross pair and matcher: matches, inliers, failed, corner error from the consensus.

    Parameters
    ----------
    kind, name : str
        The kind of scene and the group, object or scene the pairs come from.
    pairs : iterable of (label, reference, current)
        The cross-lighting pairs (images as :func:`match_pair` takes them).
    H_consensus : (3, 3) ndarray
        The transform the pairs should register to.
    matchers : tuple of Matcher
    """
    rows = []
    for label, reference, current in pairs:
        for matcher in matchers:
            m = match_pair(reference, current, matcher)
            err = float("nan") if m.failed else corner_error_px(m.H_cur_ref, H_consensus, reference.shape[:2])
            rows.append(
                {
                    "kind": kind,
                    "name": name,
                    "pair": label,
                    "matcher": str(matcher),
                    "matches": m.matches,
                    "inliers": m.inliers,
                    "failed": m.failed,
                    "corner_px": err,
                }
            )
    return rows


def consensus_homography(homographies: list[np.ndarray]) -> np.ndarray | None:
    """The element-wise median of homographies normalised to ``H[2, 2] = 1`` (None when there are none).

    Parameters
    ----------
    homographies : list of (3, 3) ndarray
    """
    if not homographies:
        return None
    stack = np.stack([H / H[2, 2] for H in homographies])
    return np.median(stack, axis=0)


def same_lighting_consensus(references: list, currents: list) -> tuple[np.ndarray | None, float, str]:
    """The consensus of an observation pair taken under the same lightings, and its spread.

    Parameters
    ----------
    references, currents : lists of images
        The two observations, one image per lighting, in the same order.

    Returns
    -------
    (H_consensus or None, spread_px, reason)
        The median of the same-lighting homographies (None below :data:`MIN_CONSENSUS`
        registrations, ``reason`` saying so), and the median corner distance of those
        homographies from it (px).
    """
    good = [m.H_cur_ref for m in (match_pair(r, c) for r, c in zip(references, currents)) if not m.failed]
    if len(good) < MIN_CONSENSUS:
        return None, float("nan"), f"{len(good)} of {len(references)} same-lighting registrations: no consensus"
    H_c = consensus_homography(good)
    shape = references[0].shape[:2]
    return H_c, float(np.median([corner_error_px(H, H_c, shape) for H in good])), ""


def corner_error_px(H: np.ndarray, H_consensus: np.ndarray, shape: tuple[int, int]) -> float:
    """Mean distance (px) between the four image corners mapped by ``H`` and by ``H_consensus``.

    Parameters
    ----------
    H, H_consensus : (3, 3) ndarray
        Homographies reference -> current.
    shape : (height, width)
        The reference image's size.
    """
    h, w = shape
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [w - 1, h - 1, 1], [0, h - 1, 1]], dtype=float).T

    def mapped(M):
        p = M @ corners
        return p[:2] / p[2]

    return float(np.mean(np.linalg.norm(mapped(H) - mapped(H_consensus), axis=0)))


def summarise(rows: list[dict]) -> dict:
    """Failure rate, corner-error quantiles and the fraction beyond 1 and 3 px of scored pairs.

    Parameters
    ----------
    rows : list of dict
        One per cross-lighting pair, with ``failed`` (bool), ``matches``, ``inliers`` and
        ``corner_px`` (float, NaN when failed).

    Returns
    -------
    dict
        ``pairs``, ``fail_rate``, ``over1_rate``, ``over3_rate`` (failed pairs count as beyond),
        ``median_corner_px`` (over the registered pairs), ``p90_corner_px``, ``median_matches``,
        ``median_inliers``, ``median_afd_px``.
    """
    n = len(rows)
    if n == 0:
        return {"pairs": 0}
    failed = np.array([r["failed"] for r in rows])
    err = np.array([r["corner_px"] if not r["failed"] else np.inf for r in rows], dtype=float)
    ok = err[np.isfinite(err)]
    afd = np.array([r.get("afd_px", np.nan) for r in rows], dtype=float)
    return {
        "pairs": n,
        "fail_rate": float(failed.mean()),
        "over1_rate": float(np.mean(err > 1.0)),
        "over3_rate": float(np.mean(err > 3.0)),
        "median_corner_px": float(np.median(ok)) if len(ok) else float("nan"),
        "p90_corner_px": float(np.quantile(ok, 0.9)) if len(ok) else float("nan"),
        "median_matches": float(np.median([r["matches"] for r in rows])),
        "median_inliers": float(np.median([r["inliers"] for r in rows])),
        "median_afd_px": float(np.nanmedian(afd)) if np.isfinite(afd).any() else float("nan"),
    }
