"""Part (c) of ``fgcd bench changes``: real objects under real light, with nothing changed or a known change.

``../shared/data/multilight/<object>/`` holds one fixed camera's photographs of an
object under 12 point lights (its README). The reference observation is 6 of them
(seeded); the current observation is the same 6, as a revisit would take them: the
object resampled by a relocation residual (:data:`MOTION_PX`, :data:`MOTION_DEG`),
each lighting scaled by its own gain (the lamp and the exposure are never quite the
same, :data:`GAIN_RANGE`) and given fresh sensor noise (:func:`sensor_noise_dn`),
re-quantised to 8 bits. Two pairs per object:

- **no change**: every region the user's ``fgcd diff`` reports is false;
- **injected change**: a stain (darker, browner albedo) and a whitening (a brighter
  albedo, salt bloom) painted on the object before the resampling, under every light
  alike (an albedo change multiplies the light an area sends back); both must be
  found, and nothing else.

Each pair runs ``fgcd diff --ref … --cur …`` with a user's defaults (no region of
interest) through its use case (:func:`fgcd_cli.app.diff.detect_bare`), on
PNG files written to a temporary folder. The detector never sees the object's mask
(it only places the painted changes) nor the painted areas (the scorer's truth).
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.bench.paths import MULTILIGHT
from fgcd_cli.changes.io import read_image
from fgcd_cli.metrics.change_scores import region_counts

__all__ = ["run_multilight", "revisit_images", "InjectedChange", "sensor_noise_dn"]

#: The relocation residual of the revisit: a shift of this many pixels (seeded direction) ...
MOTION_PX = 0.6
#: ... and a turn of this many degrees about the image centre (the issue's no-change protocol).
MOTION_DEG = 0.1
#: Each lighting's gain is drawn from this range (lamp output and exposure differ between visits).
GAIN_RANGE = (0.9, 1.1)
#: Lightings per observation, drawn (seeded) from the 12.
LIGHTINGS = 6
#: Radius (px) of a painted change: a few millimetres on these ~300 px objects.
CHANGE_RADIUS_PX = 9.0
#: The stain's per-channel albedo factor (R, G, B): darker and browner.
STAIN_FACTOR = (0.75, 0.62, 0.5)
#: The whitening's albedo factor: brighter, neutral.
WHITENING_FACTOR = (1.35, 1.35, 1.35)


@dataclass(frozen=True)
class InjectedChange:
    """One painted change: its name, centre (x, y) in reference pixels, radius (px) and albedo factor (RGB)."""

    name: str
    centre_xy: tuple[float, float]
    radius_px: float
    factor: tuple[float, float, float]


def sensor_noise_dn(level_dn: np.ndarray) -> np.ndarray:
    """Standard deviation (DN) of an 8-bit camera's noise at a level (DN): read noise and shot noise.

    Model: ``sigma^2 = 1.0^2 + 0.03 * level`` (1 DN of read noise; 2.2 DN at mid-grey), the
    order of an 8-bit machine-vision camera's; the real images keep their own noise besides.
    """
    return np.sqrt(1.0 + 0.03 * np.maximum(np.asarray(level_dn, dtype=np.float64), 0.0))


def _paint(image: np.ndarray, changes: list[InjectedChange]) -> np.ndarray:
    """``image`` (H, W, 3) float DN with each change's albedo factor, soft-edged (1 px ramp)."""
    h, w = image.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    out = image.astype(np.float64).copy()
    for change in changes:
        distance = np.hypot(xx - change.centre_xy[0], yy - change.centre_xy[1])
        weight = np.clip(change.radius_px + 0.5 - distance, 0.0, 1.0)[:, :, None]
        out *= 1.0 + weight * (np.asarray(change.factor) - 1.0)
    return out


def change_truth(shape: tuple[int, int], changes: list[InjectedChange]) -> np.ndarray:
    """The painted areas (H, W) bool, in the reference frame."""
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    truth = np.zeros(shape, bool)
    for change in changes:
        truth |= np.hypot(xx - change.centre_xy[0], yy - change.centre_xy[1]) <= change.radius_px
    return truth


def revisit_images(
    reference: list[np.ndarray], *, rng: np.random.Generator, changes: list[InjectedChange] = ()
) -> list[np.ndarray]:
    """The current observation of ``reference`` (list of (H, W, 3) uint8): painted, moved, gained, noisy.

    The motion is one rigid image motion for every lighting (the camera does not move between
    them); gains and noise are drawn per lighting.
    """
    h, w = reference[0].shape[:2]
    angle = rng.uniform(0.0, 2.0 * math.pi)
    turn = MOTION_DEG * rng.choice([-1.0, 1.0])
    A = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), turn, 1.0)
    A[:, 2] += MOTION_PX * np.array([math.cos(angle), math.sin(angle)])
    out = []
    for image in reference:
        painted = _paint(image.astype(np.float64), list(changes))
        # Lanczos: a camera that samples the scene at a new phase adds no blur, a bilinear resampling would
        moved = cv2.warpAffine(painted, A, (w, h), flags=cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REPLICATE)
        moved *= rng.uniform(*GAIN_RANGE)
        moved += rng.standard_normal(moved.shape) * sensor_noise_dn(moved)
        out.append(np.clip(np.round(moved), 0, 255).astype(np.uint8))
    return out


def _place_changes(mask: np.ndarray, rng: np.random.Generator) -> list[InjectedChange]:
    """A stain and a whitening at seeded places well inside the object, apart from each other."""
    inside = cv2.erode(mask.astype(np.uint8), np.ones((31, 31), np.uint8)) > 0
    ys, xs = np.nonzero(inside)
    first = rng.integers(len(xs))
    far = np.hypot(xs - xs[first], ys - ys[first]) > 6 * CHANGE_RADIUS_PX
    second = rng.choice(np.flatnonzero(far)) if far.any() else (first + len(xs) // 2) % len(xs)
    return [
        InjectedChange("stain", (float(xs[first]), float(ys[first])), CHANGE_RADIUS_PX, STAIN_FACTOR),
        InjectedChange("whitening", (float(xs[second]), float(ys[second])), CHANGE_RADIUS_PX, WHITENING_FACTOR),
    ]


def _detect(reference: list[np.ndarray], current: list[np.ndarray]):
    """``fgcd diff --ref ref-*.png --cur cur-*.png`` with a user's defaults, on files (the user's path)."""
    from fgcd_cli.app.diff import BareDiffRequest, detect_bare

    with tempfile.TemporaryDirectory(prefix="fgcd-multilight-") as tmp:
        folder = Path(tmp)
        for k, (ref, cur) in enumerate(zip(reference, current)):
            cv2.imwrite(str(folder / f"ref-{k}.png"), cv2.cvtColor(ref, cv2.COLOR_RGB2BGR))
            cv2.imwrite(str(folder / f"cur-{k}.png"), cv2.cvtColor(cur, cv2.COLOR_RGB2BGR))
        request = BareDiffRequest(
            ref=[str(folder / f"ref-{k}.png") for k in range(len(reference))],
            cur=[str(folder / f"cur-{k}.png") for k in range(len(current))],
            output=folder / "never-written",
        )
        return detect_bare(request).result


def score_object(folder: Path, *, seed: int) -> dict:
    """The no-change and the injected-change pair of one object, scored (false regions, changes found)."""
    rng = np.random.default_rng([seed, sum(folder.name.encode())])
    names = sorted(rng.choice(12, size=LIGHTINGS, replace=False).tolist())
    reference = [read_image(folder / f"light-{k:02d}.png") for k in names]
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    shape = reference[0].shape[:2]
    unchanged = _detect(reference, revisit_images(reference, rng=rng))
    nothing = region_counts(unchanged.mask, np.zeros(shape, bool))
    changes = _place_changes(mask, rng)
    truth = change_truth(shape, changes)
    changed = _detect(reference, revisit_images(reference, rng=rng, changes=changes))
    counts = region_counts(changed.mask, truth)
    return {
        "object": folder.name,
        "lightings": names,
        "no_change_regions": nothing.regions,
        "no_change_area_px": int(unchanged.mask.sum()),
        "injected": [c.name for c in changes],
        "injected_found": counts.changes_found,
        "injected_true": counts.changes_true,
        "injected_false_regions": counts.false_regions,
        "injected_comparable": bool(changed.comparable),
    }


def run_multilight(*, quick: bool, root: Path = MULTILIGHT, seed: int = 0) -> dict:
    """Part (c): every object under ``root`` (quick: the first two), no change and injected change."""
    objects = sorted(p for p in root.glob("*") if (p / "mask.png").is_file() and (p / "light-00.png").is_file())
    if not objects:
        return {"available": False, "reason": f"no multi-light objects under {root}"}
    if quick:
        objects = objects[:2]
    rows = [score_object(folder, seed=seed) for folder in objects]
    injected_true = sum(r["injected_true"] for r in rows)
    return {
        "available": True,
        "objects": rows,
        "multilight_false_regions": int(sum(r["no_change_regions"] for r in rows)),
        "multilight_injected_found_fraction": (
            sum(r["injected_found"] for r in rows) / injected_true if injected_true else float("nan")
        ),
        "multilight_injected_false_regions": int(sum(r["injected_false_regions"] for r in rows)),
    }
