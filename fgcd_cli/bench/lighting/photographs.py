"""The Table 1 protocol on real photographs: the FGCD groups and the multi-light objects.

FGCD groups (``fgcd-dataset/<kind>/<group>/``): observation 2 is the
reference, observation 1 the revisit; lighting 1 is the environment light,
2-7 six side lights. The consensus is the median of the 7 same-lighting
homographies; the cross pairs are the reference under the environment light
against the revisit under each side light.

Multi-light objects (``multilight/<object>/``): one fixed camera, 12 lights.
The revisit is each image resampled by a known sub-pixel motion
(:data:`KNOWN_MOTION`), so the consensus is known exactly; the reference is
the most frontal light, the cross pairs every other light against it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.app.diff import measure_fdf
from fgcd_cli.bench.lighting.cross_light import (
    Matcher,
    corner_error_px,
    match_pair,
    same_lighting_consensus,
    score_pairs,
)
from fgcd_core.flash import lamp_only_image
from fgcd_core.imaging import to_gray_f32

__all__ = [
    "FGCD_KINDS",
    "LAMP_MATCHERS",
    "lamp_pairs",
    "KNOWN_MOTION",
    "MULTILIGHT_KIND",
    "failed_counts",
    "fgcd_group_rows",
    "frontal_light",
    "known_motion",
    "multilight_rows",
    "resampled",
]

#: The dataset's folders and the kind of scene each holds (its README).
FGCD_KINDS = {"Db": "test_block", "Dp": "outdoor_relief", "Ds": "statue"}
#: The multi-light objects' kind.
MULTILIGHT_KIND = "multilight_object"
#: The revisit's motion on the multi-light images: 0.6 px right, 0.4 px down, 0.1 deg about the centre
#: (the README's no-change check: a sub-pixel motion, as a relocation leaves).
KNOWN_MOTION = (0.6, 0.4, 0.1)


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise OSError(f"cannot read {path}")
    return image


def _afd(reference: np.ndarray, current: np.ndarray) -> float:
    """The AFD ``fgcd afd`` reports for the pair (px), NaN when it cannot measure it."""
    fdf = measure_fdf(reference, current)
    return float("nan") if fdf is None else float(fdf.afd_px)


def _pair_rows(kind: str, name: str, pairs: list, consensus: np.ndarray, afd_same: float) -> list[dict]:
    """Every matcher's rows of ``pairs``, and the AFD ``fgcd afd`` reports for each (on its SIFT row)."""
    rows = score_pairs(kind, name, pairs, consensus)
    afd = {label: _afd(ref, cur) for label, ref, cur in pairs}
    for row in rows:
        if row["matcher"] == Matcher.SIFT:
            row["afd_px"] = afd[row["pair"]]
            row["afd_error_px"] = abs(afd[row["pair"]] - afd_same)
    return rows


def failed_counts(rows: list[dict]) -> str:
    """``failed: sift 1/6, image_stage 0/6, grid 2/6``."""
    counts = {}
    for r in rows:
        n, f = counts.get(r["matcher"], (0, 0))
        counts[r["matcher"]] = (n + 1, f + int(r["failed"]))
    return "failed: " + ", ".join(f"{m} {f}/{n}" for m, (n, f) in counts.items())


def fgcd_group_rows(group: Path, *, say: Callable = print) -> dict:
    """The cross-lighting rows of one FGCD group, with its same-lighting spread.

    Every lighting both observations hold is used (a group may lack one); lighting 1,
    the environment light, is the reference's, the others are the revisit's side lights.

    Parameters
    ----------
    group : Path
        ``fgcd-dataset/<kind>/<group>``.

    Returns
    -------
    dict
        ``rows`` (one per cross pair; empty without a consensus), ``same_light_spread_px``
        (median corner distance of the same-lighting homographies from their consensus),
        ``reason`` when the group could not be scored.
    """
    kind = FGCD_KINDS.get(group.parent.name, group.parent.name)
    lightings = [k for k in range(1, 8) if (group / f"1-{k}.png").exists() and (group / f"2-{k}.png").exists()]
    if 1 not in lightings:
        return {"rows": [], "reason": "no environment-light pair (1-1, 2-1)"}
    ref = {k: _read(group / f"2-{k}.png") for k in lightings}
    cur = {k: _read(group / f"1-{k}.png") for k in lightings}
    H_c, spread, reason = same_lighting_consensus([ref[k] for k in lightings], [cur[k] for k in lightings])
    if H_c is None:
        return {"rows": [], "reason": reason}
    afd_same = _afd(ref[1], cur[1])
    pairs = [(f"2-1/1-{k}", ref[1], cur[k]) for k in lightings if k != 1]
    rows = _pair_rows(kind, group.name, pairs, H_c, afd_same)
    lamp = score_pairs(kind, group.name, lamp_pairs(ref, cur, lightings), H_c, matchers=LAMP_MATCHERS)
    say(f"real {group.name}: same-lighting spread {spread:.2f} px, {failed_counts(rows)}")
    return {"rows": rows, "lamp_rows": [{**r, "pairing": "lamp"} for r in lamp], "same_light_spread_px": spread}


#: The matchers the relocation's image stage uses, measured on the lamp's own images.
LAMP_MATCHERS = (Matcher.SIFT, Matcher.IMAGE_STAGE, Matcher.GRID)


def lamp_pairs(ref: dict, cur: dict, lightings: list[int]) -> list:
    """Each side light's own image in each observation (that light's still minus the environment's,
    ``fgcd_core.flash.lamp_only_image``; the image the relocation measures on, docs/relocation.md,
    "The lamp's own image"), paired across the observations. The FGCD photographs were not taken at
    one locked exposure, so the difference is the side light alone only where the exposure held;
    a lighting whose difference holds no light is left out."""
    out = []
    for k in lightings:
        if k == 1:
            continue
        try:
            pair = (
                lamp_only_image(to_gray_f32(ref[k]), to_gray_f32(ref[1])).image,
                lamp_only_image(to_gray_f32(cur[k]), to_gray_f32(cur[1])).image,
            )
        except ValueError:
            continue
        out.append((f"2-{k}-2-1/1-{k}-1-1", *pair))
    return out


def known_motion(shape: tuple[int, int], motion: tuple[float, float, float] = KNOWN_MOTION) -> np.ndarray:
    """The (3, 3) homography of a shift ``(dx, dy)`` px and a rotation ``deg`` about the image centre."""
    h, w = shape
    dx, dy, deg = motion
    A = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), deg, 1.0)
    A[:, 2] += (dx, dy)
    return np.vstack([A, [0.0, 0.0, 1.0]])


def resampled(image: np.ndarray, H_cur_ref: np.ndarray) -> np.ndarray:
    """``image`` as a camera moved by ``H_cur_ref`` sees it (bilinear, borders replicated)."""
    h, w = image.shape[:2]
    return cv2.warpPerspective(image, H_cur_ref, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def frontal_light(directions: np.ndarray) -> int:
    """Index of the light nearest the viewing direction (largest z toward the camera)."""
    return int(np.argmax(directions[:, 2]))


def multilight_rows(obj: Path, directions: np.ndarray, *, say: Callable = print) -> dict:
    """The cross-lighting rows of one multi-light object (fixed camera; the known motion is the consensus).

    Parameters
    ----------
    obj : Path
        ``multilight/<object>`` with ``light-00.png`` ... ``light-11.png``.
    directions : (12, 3) ndarray
        The lights (``lights.txt``), unused but for choosing the reference light.
    """
    images = [_read(obj / f"light-{i:02d}.png") for i in range(len(directions))]
    H_known = known_motion(images[0].shape[:2])
    ref_index = frontal_light(directions)
    reference = images[ref_index]
    afd_same = _afd(reference, resampled(reference, H_known))
    pairs = [
        (f"light-{ref_index:02d}/light-{i:02d}", reference, resampled(images[i], H_known))
        for i in range(len(images))
        if i != ref_index
    ]
    rows = _pair_rows(MULTILIGHT_KIND, obj.name, pairs, H_known, afd_same)
    same = match_pair(reference, resampled(reference, H_known))
    spread = float("nan") if same.failed else corner_error_px(same.H_cur_ref, H_known, reference.shape[:2])
    say(f"real {obj.name}: same-lighting error {spread:.2f} px, {failed_counts(rows)}")
    return {"rows": rows, "same_light_spread_px": spread}
