"""A-contrario decision: which high-score regions are changes, with a stated meaning.

The rule (Desolneux, Moisan & Morel, *From Gestalt Theory to Image Analysis*,
2008, ch. 3-4): a candidate region is reported when its **number of false
alarms** is below ``epsilon``,

    NFA(R) = N_tests * P_H0(R),

i.e. when fewer than ``epsilon`` regions at least as extreme are expected, per
image, if nothing had changed. The background model H0 is taken from the pair
itself, so no threshold is tuned on other data:

* **marginal**: the empirical distribution of the pair's own score over the
  compared pixels: whatever heavy tail the texture, cast shadows or
  misregistration give this pair is in it by construction. Per-pixel
  ``-log p``, with ``p`` the larger of the empirical survival ``P(S >= s)`` and
  that of half-normal sensor noise with the score's median (a pixel is only as
  surprising as its least surprising explanation). Changes covering more than
  ``seed_p`` of the frame do move the empirical tail (see the strict ``xfail``
  tests in ``tests/changes/test_significance.py``).
* **dependence**: neighbouring scores are not independent (smoothing,
  demosaicing, texture edges), so a region of ``n`` pixels holds only
  ``n / A`` independent samples. ``A`` is the mean size of the connected
  clusters of exceedances at the seed level: the reciprocal of the extremal
  index of extreme-value theory (Leadbetter 1983), estimated on the pair,
  re-estimated without the clusters found significant (changes are not the
  background's dependence), and at least the correlation area of the score's
  smoothing (passed by the caller).
* **region probability**: under H0 the ``n_eff`` independent samples of a
  region found at level ``lambda = -log p_level`` all exceed it with
  probability ``exp(-lambda n_eff)``, and, given that, their excesses of
  ``-log p`` over ``lambda`` are i.i.d. Exp(1), so their sum exceeds the
  observed one with probability ``Q(n_eff, excess)`` (regularized upper
  incomplete gamma). ``P_H0(R) = exp(-lambda n_eff) Q(n_eff, excess / A)``.
* **tests**: connected components of ``{p <= p_level}`` for a ladder of levels
  from ``seed_p`` down to the most extreme score; ``N_tests = (N / A) * levels``.

Regions are accepted most significant first, without overlap (the exclusion
principle); each is then grown to its extent (pixels connected to it whose
score excess over the background median is at least ``extent_fraction`` of its
peak excess: the flank of a smoothed change, as a half-maximum rule is for a
blob). The two constants that are not fixed by the model (``seed_p``,
``extent_fraction``) are chosen by leave-one-group-out in ``fgcd bench
changes``; see ``docs/change-detection.md``, "Significance of each region (a-contrario)".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, special

from fgcd_cli.changes.config import EPSILON, RegionConfig
from fgcd_cli.changes.extent import grow_to_extent
from fgcd_cli.changes.marginal import halfnormal_neglog_survival, scan_neglogp

_EIGHT = np.ones((3, 3), bool)


@dataclass(kw_only=True)
class SignificantRegion:
    """One region that passed (or, for candidates, missed) the a-contrario test."""

    log10_nfa: float
    """log10 of the number of false alarms: below log10(epsilon) = significant (0 for epsilon = 1)."""
    p_level: float
    """Empirical survival probability of the level at which the region was found."""
    area_px: int
    """Pixels of the component at that level (before growing to its extent)."""
    centroid_xy: tuple[float, float]
    peak_score: float
    why: str = ""
    """For a candidate: why it was not reported (:data:`fgcd_cli.changes.result.WHY_NOT_REPORTED`)."""


@dataclass(frozen=True, kw_only=True)
class ScanNull:
    """The null one scan decided under, kept so that another map of the same pair can be tested
    against it (:mod:`fgcd_cli.changes.rescan`)."""

    sorted_background: np.ndarray
    """(M,) float32, the background pixels' scores, ascending (the empirical marginal)."""
    median: float
    """Median score over the compared pixels (the half-normal floor's scale)."""
    area: float
    n_tests: float
    levels: np.ndarray
    """The ladder of ``-log p`` levels scanned."""
    epsilon: float


@dataclass(kw_only=True)
class Decision:
    """Result of :func:`acontrario_decision`."""

    mask: np.ndarray
    """HxW bool, pixels of the significant regions grown to their extent."""
    regions: list[SignificantRegion]
    """Significant regions, most significant first."""
    candidates: list[SignificantRegion]
    """The strongest regions that did not pass (most significant first; at most 5)."""
    cluster_area_px: float
    """A, pixels per independent sample (the extremal index's reciprocal)."""
    n_tests: float
    seed_level: float
    """Score at the seed probability ``seed_p`` (the lowest level tested)."""
    median: float
    """Median score over the compared pixels (the background level)."""
    seed_index: np.ndarray | None = None
    """HxW int32: i + 1 on the seed pixels of ``regions[i]``, 0 elsewhere."""
    settings: dict = field(default_factory=dict)
    nulls: tuple[ScanNull, ...] = ()
    """The null of each score map scanned (one per map, in order)."""


def exceedance_cluster_area(
    score: np.ndarray, valid: np.ndarray, level: float, exclude: np.ndarray | None = None
) -> float:
    """Mean size (px) of the 8-connected clusters of ``score >= level`` (at least 1).

    Clusters touching ``exclude`` (regions already found significant) do not count:
    where changes cover more than the seed probability, the clusters at the seed
    level are mostly changes, and their size is not the background's dependence.
    """
    labels, count = ndimage.label((score >= level) & valid, structure=_EIGHT)
    if count == 0:
        return 1.0
    sizes = np.bincount(labels.ravel(), minlength=count + 1)[1:]
    if exclude is not None and exclude.any():
        touched = np.unique(labels[exclude & (labels > 0)])
        keep = np.ones(count, bool)
        keep[touched - 1] = False
        if keep.any():
            sizes = sizes[keep]
    return max(1.0, float(np.mean(sizes)))


def _log_region_probability(lam: float, sizes: np.ndarray, excess: np.ndarray, area: float) -> np.ndarray:
    """log P_H0 of regions found at level ``lam`` (see the module docstring)."""
    n_eff = np.maximum(sizes / area, 1.0)
    tail = special.gammaincc(n_eff, np.maximum(excess, 0.0) / area)
    return -lam * n_eff + np.log(np.maximum(tail, 1e-300))


@dataclass(frozen=True, kw_only=True)
class AcontrarioConfig:
    """Constants of :func:`acontrario_decision` (the module docstring gives the model)."""

    epsilon: float = EPSILON
    """Expected number of false regions per image tolerated under the pair's own no-change model
    (1: at most one false region expected per image)."""
    seed_p: float = 0.005
    """Lowest level tested, as an empirical survival probability."""
    extent_fraction: float = 0.2
    """In [0, 1): a region grows into connected pixels whose excess over the median score is at
    least this fraction of its peak excess (0: the component at its level)."""
    level_step: float = 0.25
    """Spacing of the ladder of levels, in ``-log p`` (0.25: ~28 % apart in probability)."""
    max_candidates: int = 5
    """Non-significant regions kept for "no significant change; strongest candidate ..."."""
    area_rounds: int = 3
    """Re-estimations of the cluster area without the clusters found significant."""
    null_rounds: int = 2
    """Re-estimations of the null distribution without the regions found (and their correlation
    radius); 0 keeps the null of all compared pixels."""
    score_maps: int = 1
    """Score maps of the pair tested with this decision (e.g. two smoothings of one score): the
    number of tests counts the regions of all of them, so epsilon stays per image."""


def acontrario_config(regions: RegionConfig) -> AcontrarioConfig:
    """The test's constants a detector's :class:`~fgcd_cli.changes.config.RegionConfig` sets
    (``epsilon``, ``seed_p``, ``extent_fraction``); the others keep their defaults."""
    return AcontrarioConfig(epsilon=regions.epsilon, seed_p=regions.seed_p, extent_fraction=regions.extent_fraction)


def acontrario_decision(
    score: np.ndarray,
    valid: np.ndarray,
    *,
    min_cluster_area_px: float = 1.0,
    config: AcontrarioConfig | None = None,
) -> Decision:
    """Significant change regions of a score map, by their number of false alarms.

    Parameters
    ----------
    score : ndarray, HxW float
        Change score, larger = more likely changed (any monotone scale).
    valid : ndarray, HxW bool
        Compared pixels: they define the background distribution and may be flagged.
    min_cluster_area_px : float
        Lower bound of the cluster area: a score smoothed with a Gaussian of sigma
        ``s`` px has a correlation area of at least ``4 pi s^2`` px whatever its
        exceedance clusters look like (the caller passes it).
    config : AcontrarioConfig, optional
        The test's constants (default: :class:`AcontrarioConfig`).

    Returns
    -------
    Decision
    """
    config = config or AcontrarioConfig()
    valid = np.asarray(valid, bool)
    score = np.asarray(score, np.float32)
    n_valid = int(valid.sum())
    if n_valid == 0:
        raise ValueError("no valid pixel to decide on")
    median = float(np.median(score[valid]))
    # A pixel is only as surprising as its least surprising explanation: the pair's
    # empirical tail, or sensor-like noise (half-normal with the score's median as
    # its median). Without the second, the top fraction of an unchanged, nearly
    # noise-free pair is "significant" whenever it is spatially structured.
    halfnormal = halfnormal_neglog_survival(score / max(median, 1e-12))
    background = valid
    scan = _Scan(significant=np.zeros(valid.shape, bool))
    null_round = 0
    while True:
        scan = _scan_with_null(
            score, valid, background, halfnormal, previous=scan, min_cluster_area_px=min_cluster_area_px, config=config
        )
        mask = grow_to_extent(scan.significant, score, valid, background=median, fraction=config.extent_fraction)
        # The null is the distribution of the *unchanged* pixels: once regions are found,
        # it is re-estimated without them (grown by the correlation radius), so that a
        # strong or extended change no longer fattens the tail that weaker ones are
        # judged against. Stops when the found set no longer grows.
        if null_round >= config.null_rounds or not mask.any():
            break
        grow = int(np.ceil(np.sqrt(min_cluster_area_px / np.pi)))
        changed = ndimage.binary_dilation(mask, structure=_EIGHT, iterations=max(grow, 1))
        new_background = valid & ~changed
        if new_background.sum() < 0.5 * n_valid or np.array_equal(new_background, background):
            break
        background = new_background
        null_round += 1
    return Decision(
        mask=mask,
        regions=scan.regions,
        candidates=scan.candidates,
        cluster_area_px=scan.area,
        n_tests=float(scan.n_tests),
        seed_level=scan.seed_level,
        median=median,
        seed_index=scan.seed_index,
        nulls=(_kept_null(score, background, median, scan, config),),
        settings={
            "epsilon": config.epsilon,
            "seed_p": config.seed_p,
            "extent_fraction": config.extent_fraction,
            "level_step": config.level_step,
            "levels": scan.levels,
            "null_rounds": null_round,
        },
    )


@dataclass(kw_only=True)
class _Scan:
    """One scan of the ladder of levels under one null (see :func:`_scan_with_null`)."""

    significant: np.ndarray
    regions: list[SignificantRegion] = field(default_factory=list)
    candidates: list[SignificantRegion] = field(default_factory=list)
    seed_index: np.ndarray | None = None
    area: float = 1.0
    """The cluster area the scan used."""
    n_tests: float = 0.0
    seed_level: float = 0.0
    levels: int = 0
    ladder: np.ndarray | None = None
    """The ``-log p`` levels scanned."""


def _kept_null(score, background, median: float, scan: _Scan, config: AcontrarioConfig) -> ScanNull:
    """The null the last scan decided under (its background's scores, sorted), for :mod:`fgcd_cli.changes.rescan`."""
    return ScanNull(
        sorted_background=np.sort(score[background]),
        median=median,
        area=scan.area,
        n_tests=float(scan.n_tests),
        levels=scan.ladder if scan.ladder is not None else np.zeros(0),
        epsilon=config.epsilon,
    )


def _scan_with_null(
    score, valid, background, halfnormal, *, previous: _Scan, min_cluster_area_px: float, config: AcontrarioConfig
) -> _Scan:
    """Scan the levels under the null of the ``background`` pixels, re-estimating the cluster area
    without the clusters found significant until it settles (at most ``area_rounds`` times)."""
    n_valid = int(valid.sum())
    significant = previous.significant
    neglogp = scan_neglogp(np.sort(score[background & valid]), score, valid, halfnormal, floor=-np.log(config.seed_p))
    seed_level = float(np.quantile(score[background], 1.0 - config.seed_p))
    area = max(exceedance_cluster_area(score, valid, seed_level, exclude=significant), min_cluster_area_px)
    levels = np.arange(-np.log(config.seed_p), float(neglogp.max()) + 1e-9, config.level_step)
    # The components depend on the levels only, not on the cluster area: found once for every round.
    components = level_components(neglogp, valid, levels)
    for _ in range(config.area_rounds + 1):
        n_tests = n_valid / area * max(len(levels), 1) * config.score_maps
        regions, candidates, significant, seed_index = scan_levels(
            score,
            levels,
            components,
            area=area,
            n_tests=n_tests,
            epsilon=config.epsilon,
            max_candidates=config.max_candidates,
        )
        used_area = area
        area = max(exceedance_cluster_area(score, valid, seed_level, exclude=significant), min_cluster_area_px)
        if area == used_area:
            break
    return _Scan(
        significant=significant,
        regions=regions,
        candidates=candidates,
        seed_index=seed_index,
        area=used_area,
        n_tests=n_tests,
        seed_level=seed_level,
        levels=int(len(levels)),
        ladder=levels,
    )


def _level_components(neglogp, valid, levels):
    """Every connected component of every level: (log-level index, size, excess, absolute bounding box,
    its pixels inside the box).

    A component of a higher level lies inside one component of the lowest level, so each lowest-level
    component is labelled again level by level inside its own bounding box (the exceedances of a pair
    cover a few percent of the frame): the same components as labelling the whole frame at every level.
    """
    base, _ = ndimage.label((neglogp >= levels[0]) & valid, structure=_EIGHT)
    for j, window in enumerate(ndimage.find_objects(base), start=1):
        if window is None:
            continue
        inside = base[window] == j
        local_neglogp = neglogp[window]
        for k, lam in enumerate(levels):
            labels, count = ndimage.label((local_neglogp >= lam) & inside, structure=_EIGHT)
            if count == 0:
                break  # the levels above are subsets of this one
            flat = labels.ravel()
            sizes = np.bincount(flat, minlength=count + 1)[1:].astype(np.float64)
            excess = np.bincount(flat, weights=(local_neglogp - np.float32(lam)).ravel(), minlength=count + 1)[1:]
            for i, box in enumerate(ndimage.find_objects(labels)):
                absolute = tuple(slice(w.start + b.start, w.start + b.stop) for w, b in zip(window, box))
                yield k, sizes[i], excess[i], absolute, labels[box] == i + 1


def level_components(neglogp, valid, levels) -> list[list]:
    """Per level, its connected components as ``(size, excess, absolute bounding box, pixels in the box)``."""
    per_level: list[list] = [[] for _ in levels]
    if len(levels):
        for k, size, excess, window, component in _level_components(neglogp, valid, levels):
            per_level[k].append((size, excess, window, component))
    return per_level


def scan_levels(score, levels, per_level, *, area, n_tests, epsilon, max_candidates):
    """The NFA of every level's components and the exclusion principle (most significant first).

    ``per_level``: :func:`level_components` of the score's ``-log p`` at ``levels`` (they do not depend on
    ``area`` or ``n_tests``, so the cluster-area rounds of one null share them).
    """
    found = []
    for lam, components in zip(levels, per_level):
        if not components:
            continue
        sizes = np.array([c[0] for c in components], np.float64)
        excess = np.array([c[1] for c in components], np.float64)
        log_nfa = np.log(n_tests) + _log_region_probability(float(lam), sizes, excess, area)
        # per level, the significant components and the strongest others (4x as many as are listed)
        order = np.argsort(log_nfa, kind="stable")
        keep = int((log_nfa < np.log(epsilon)).sum()) + 4 * max_candidates
        found.extend((float(log_nfa[i]), float(lam), components[i][2], components[i][3]) for i in order[:keep])
    found.sort(key=lambda item: item[0])
    seeds = np.zeros(score.shape, bool)
    significant = np.zeros(score.shape, bool)
    seed_index = np.zeros(score.shape, np.int32)
    regions: list[SignificantRegion] = []
    candidates: list[SignificantRegion] = []
    for log_nfa, lam, window, component in found:
        # Everything within the component's bounding box (``window``): the same as on the whole frame.
        if (component & seeds[window]).any():
            continue
        ys, xs = np.nonzero(component)
        entry = SignificantRegion(
            log10_nfa=log_nfa / np.log(10.0),
            p_level=float(np.exp(-lam)),
            area_px=int(ys.size),
            centroid_xy=(float(xs.mean() + window[1].start), float(ys.mean() + window[0].start)),
            peak_score=float(score[window][component].max()),
        )
        if log_nfa < np.log(epsilon):
            seeds[window] |= component
            significant[window] |= component
            regions.append(entry)
            seed_index[window][component] = len(regions)
        elif len(candidates) < max_candidates:
            seeds[window] |= component  # a weaker, overlapping level of the same candidate is not another one
            candidates.append(entry)
    return regions, candidates, significant, seed_index


def merge_decisions(decisions: list[Decision], *, max_candidates: int) -> Decision:
    """One decision from the decisions on several score maps of one pair (each run with
    ``score_maps = len(decisions)``): the union of their masks, every region with its own NFA.

    The first decision's statistics (median, seed level, cluster area) describe the result;
    ``seed_index`` numbers the regions in the merged list (the first map's seeds win where seeds overlap).
    """
    first = decisions[0]
    if len(decisions) == 1:
        return first
    mask = np.logical_or.reduce([d.mask for d in decisions])
    regions, seed_index = [], np.zeros(first.mask.shape, np.int32)
    for d in decisions:
        if d.seed_index is not None:
            free = (seed_index == 0) & (d.seed_index > 0)
            seed_index[free] = d.seed_index[free] + len(regions)
        regions.extend(d.regions)
    # One candidate seen at both scales is listed once: the more significant one, others within
    # the main scan's correlation radius of it dropped.
    radius = float(np.sqrt(first.cluster_area_px / np.pi))
    candidates: list[SignificantRegion] = []
    for c in sorted((c for d in decisions for c in d.candidates), key=lambda c: c.log10_nfa):
        if all(
            np.hypot(c.centroid_xy[0] - k.centroid_xy[0], c.centroid_xy[1] - k.centroid_xy[1]) > radius
            for k in candidates
        ):
            candidates.append(c)
    candidates = candidates[:max_candidates]
    return Decision(
        mask=mask,
        regions=regions,
        candidates=candidates,
        cluster_area_px=first.cluster_area_px,
        n_tests=first.n_tests,
        seed_level=first.seed_level,
        median=first.median,
        seed_index=seed_index,
        settings=dict(first.settings, score_maps=len(decisions), regions_per_map=[len(d.regions) for d in decisions]),
        nulls=tuple(null for d in decisions for null in d.nulls),
    )
