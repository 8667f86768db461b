"""Following each change region across a station's visits (docs/archive.md, "Change over time").

Every visit's diff is in the reference image's frame, so one damage seen at two
visits covers the same reference pixels. Rules:

- A region's footprint is the connected component of the visit's change mask
  that fills most of its box.
- A region joins the track whose footprint so far (the union over the visits it
  was seen at), dilated by :data:`MATCH_DILATION_PX`, it overlaps most; a region
  overlapping no track starts a new one. Two regions of one visit may join one
  track (a region that split); the track's area at that visit is their sum.
- A track's area is 0 at a comparable visit after its first where no region
  joined it, and unknown (None) at a visit that could not be compared.
- Growth rate: the least-squares slope of area against time (mm² or px per
  year) over the comparable visits from its first one on.
- At the latest comparable visit a track is *new* (first seen there), *growing*
  or *shrinking* when its area changed by more than its boundary uncertainty (the
  area of the previous footprint's one-pixel boundary ring: a segmentation at
  pixel resolution can move its edge by one pixel), *gone* at area 0, else *stable*.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from enum import StrEnum

import numpy as np
from scipy import ndimage

__all__ = ["MATCH_DILATION_PX", "TrackStatus", "VisitRegions", "RegionTrack", "track_regions"]

MATCH_DILATION_PX = 2
"""Footprints are matched with this tolerance, px: the campaign diff's edge-check shift
(:data:`fgcd_cli.app.diff_options.EDGE_CHECK_PX`), the residual misregistration a relocated visit keeps."""

_SECONDS_PER_YEAR = 365.25 * 86400.0


class TrackStatus(StrEnum):
    """A tracked region at the latest comparable visit."""

    NEW = "new"
    GROWING = "growing"
    STABLE = "stable"
    SHRINKING = "shrinking"
    GONE = "gone"


@dataclass(frozen=True, kw_only=True)
class VisitRegions:
    """One visit's analysed regions.

    Attributes
    ----------
    visit : str
        The visit's name (its UTC stamp).
    date : datetime
    comparable : bool
        False when the diff could not compare the visit (its regions are then empty).
    regions : list of dict
        The regions of ``regions.json`` (``area_px``, ``area_mm2``, ``bbox_xywh``, ``centroid_xy``).
    mask : (H, W) bool ndarray
        The visit's change mask in the reference image's frame.
    """

    visit: str
    date: datetime
    comparable: bool
    regions: list[dict]
    mask: np.ndarray


@dataclass(kw_only=True)
class RegionTrack:
    """One damage followed across visits.

    Attributes
    ----------
    id : int
        1-based, in order of first appearance.
    first_seen : str
        The visit it was first seen at.
    areas : dict of str to float or None
        Area per visit from ``first_seen`` on, in ``unit`` (0: not detected; None: visit not comparable).
    unit : str
        ``mm²`` when every region had a metric area, else ``px``.
    centroid_xy : tuple of float
        Where it was last seen, reference image px.
    growth_per_year : float or None
        Least-squares slope of area against time, ``unit`` per year (None: seen at one visit only).
    status : TrackStatus
    change_since_previous : float or None
        Area at the latest comparable visit minus at the one before, ``unit``.
    """

    id: int
    first_seen: str
    areas: dict[str, float | None] = field(default_factory=dict)
    unit: str = "mm²"
    centroid_xy: tuple[float, float] = (0.0, 0.0)
    growth_per_year: float | None = None
    status: TrackStatus = TrackStatus.NEW
    change_since_previous: float | None = None
    footprint: np.ndarray | None = field(default=None, repr=False)
    footprints: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        """JSON-ready form (footprints left out)."""
        return {
            "id": self.id,
            "first_seen": self.first_seen,
            "areas": self.areas,
            "unit": self.unit,
            "centroid_xy": list(self.centroid_xy),
            "growth_per_year": self.growth_per_year,
            "status": self.status.value,
            "change_since_previous": self.change_since_previous,
        }


def _footprint(region: dict, labels: np.ndarray) -> np.ndarray:
    """The region's pixels: the connected component of the change mask that fills most of its box."""
    x, y, w, h = (int(v) for v in region["bbox_xywh"])
    inside = labels[y : y + h, x : x + w]
    ids, counts = np.unique(inside[inside > 0], return_counts=True)
    if len(ids) == 0:
        return np.zeros(labels.shape, bool)
    return labels == ids[np.argmax(counts)]


def _area(region: dict, metric: bool) -> float:
    return float(region["area_mm2"]) if metric else float(region["area_px"])


def _match(footprint: np.ndarray, tracks: list[RegionTrack]) -> RegionTrack | None:
    """The track whose footprint, dilated by MATCH_DILATION_PX, overlaps ``footprint`` most (None: none does)."""
    ys, xs = np.nonzero(footprint)
    if len(ys) == 0:
        return None
    m = MATCH_DILATION_PX  # only track pixels within m px of the region's box can reach it
    window = (slice(max(ys.min() - m, 0), ys.max() + m + 1), slice(max(xs.min() - m, 0), xs.max() + m + 1))
    best, best_overlap = None, 0
    for track in tracks:
        near = ndimage.binary_dilation(track.footprint[window], iterations=m)
        overlap = int(np.count_nonzero(near & footprint[window]))
        if overlap > best_overlap:
            best, best_overlap = track, overlap
    return best


def _assign(visit: VisitRegions, tracks: list[RegionTrack], metric: bool, unit: str) -> None:
    """Give each region of ``visit`` to a track (a new one when it overlaps none); record the tracks' areas."""
    seen: dict[int, float] = {}
    labels, _ = ndimage.label(visit.mask, structure=np.ones((3, 3), bool))
    for region in visit.regions:
        footprint = _footprint(region, labels)
        track = _match(footprint, tracks)
        if track is None:
            track = RegionTrack(
                id=len(tracks) + 1, first_seen=visit.visit, unit=unit, footprint=np.zeros_like(footprint)
            )
            tracks.append(track)
        track.footprint |= footprint
        track.footprints[visit.visit] = track.footprints.get(visit.visit, np.zeros_like(footprint)) | footprint
        track.centroid_xy = tuple(float(c) for c in region["centroid_xy"])
        seen[track.id] = seen.get(track.id, 0.0) + _area(region, metric)
    for track in tracks:
        if track.first_seen == visit.visit or track.id in seen or track.areas:
            track.areas[visit.visit] = seen.get(track.id, 0.0) if visit.comparable else None


def _boundary_area(track: RegionTrack, visit: str, per_px: float) -> float:
    footprint = track.footprints.get(visit)
    if footprint is None or not footprint.any():
        return 0.0
    ring = footprint & ~ndimage.binary_erosion(footprint)
    return float(np.count_nonzero(ring)) * per_px


def _summarise(track: RegionTrack, dates: dict[str, datetime], per_px: float, latest: str | None) -> None:
    """Growth rate, change since the previous comparable visit and status at ``latest`` (the last comparable visit)."""
    known = [(v, a) for v, a in track.areas.items() if a is not None]
    if len(known) >= 2:
        t = np.array([(dates[v] - dates[known[0][0]]).total_seconds() / _SECONDS_PER_YEAR for v, _ in known])
        a = np.array([a for _, a in known])
        track.growth_per_year = float(np.polyfit(t, a, 1)[0]) if np.ptp(t) > 0 else None
    if track.first_seen == latest:
        track.status = TrackStatus.NEW
        return
    if len(known) < 2:  # seen once, no comparable visit since: nothing says it changed
        track.status = TrackStatus.STABLE
        return
    (previous_visit, previous), (_, area) = known[-2], known[-1]
    track.change_since_previous = area - previous
    tolerance = _boundary_area(track, previous_visit, per_px)
    if area <= 0:
        track.status = TrackStatus.GONE
    elif track.change_since_previous > tolerance:
        track.status = TrackStatus.GROWING
    elif track.change_since_previous < -tolerance:
        track.status = TrackStatus.SHRINKING
    else:
        track.status = TrackStatus.STABLE


def _mean_area_per_px(visits: list[VisitRegions], metric: bool) -> float:
    if not metric:
        return 1.0
    px = sum(r["area_px"] for v in visits for r in v.regions)
    mm2 = sum(r["area_mm2"] for v in visits for r in v.regions)
    return mm2 / px if px else 1.0


def track_regions(visits: list[VisitRegions]) -> list[RegionTrack]:
    """Follow every region across ``visits`` (oldest first) by overlap in the reference frame.

    Parameters
    ----------
    visits : list of VisitRegions
        A station's analysed visits, oldest first, all masks of the reference image's shape (H, W).

    Returns
    -------
    list of RegionTrack
        In order of first appearance; areas in mm² when every region carries one, else in px.
    """
    metric = all(r.get("area_mm2") is not None for v in visits for r in v.regions)
    unit = "mm²" if metric else "px"
    tracks: list[RegionTrack] = []
    for visit in visits:
        _assign(visit, tracks, metric, unit)
    dates = {v.visit: v.date for v in visits}
    per_px = _mean_area_per_px(visits, metric)
    latest = next((v.visit for v in reversed(visits) if v.comparable), None)
    for track in tracks:
        _summarise(track, dates, per_px, latest)
    return tracks
