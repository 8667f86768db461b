"""The tiled detector at the working resolution: health, registration, dense parallax, and the photometric cue labels."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from fgcd_cli.changes.config import CueConfig, RegistrationConfig
from fgcd_cli.changes.cues.labels import label_regions, relief_colour_cues
from fgcd_cli.changes.dense.refine import DenseAlignment, refine_dense, warp_with_flow
from fgcd_cli.changes.illumination import normalize_local_gain
from fgcd_cli.changes.images import image_health
from fgcd_cli.changes.registration import Registration, RegistrationInit, register_to_reference, warp_to_reference
from fgcd_cli.changes.tiled.inputs import as_float, downscale, gray_mean
from fgcd_cli.changes.tiled.schedule import release_free_memory


@dataclass(kw_only=True)
class Small:
    """The stacks at the working resolution (8-bit kept 8-bit) and what was estimated there."""

    refs: list[np.ndarray]
    curs: list[np.ndarray]
    registration: Registration
    dense_fit: DenseAlignment | None


def working_resolution(
    ref_images, cur_images, size_wh, *, roi, config: RegistrationConfig, workers: int
) -> Small | tuple[str, str]:
    """Downscale the stacks, check them, register and refine at the working resolution.

    Returns ``(progress label, reason)`` when the pair cannot be compared.
    """
    ws, hs = size_wh
    images = list(ref_images) + list(cur_images)
    n = len(ref_images)
    pair = (config.registration_lighting, n + config.registration_lighting)

    def prepare(image):  # resizing and numpy release the GIL
        small = downscale(image, size_wh)
        gray = gray_mean(as_float(small))
        return small, gray, image_health(gray)

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        # The registration pair first: it registers here while the pool prepares the
        # other images. Any image's problem is reported before the registration's.
        order = list(pair) + [i for i in range(2 * n) if i not in pair]
        jobs = dict(zip(order, (pool.submit(prepare, images[i]) for i in order)))
        (_, gray_ref, problem_ref), (_, gray_cur, problem_cur) = jobs[pair[0]].result(), jobs[pair[1]].result()
        reg_small = Registration(H_cur_ref=np.eye(3), ok=True, init=RegistrationInit.NONE, overlap_fraction=1.0)
        if config.register and not (problem_ref or problem_cur):
            reg_small = register_to_reference(gray_ref, gray_cur)
        smalls = []
        for i in range(2 * n):
            small, _, problem = jobs.pop(i).result()
            if problem:
                label, index = ("reference", i + 1) if i < n else ("current", i - n + 1)
                return "checked", f"cannot compare: {label} image {index}: {problem}"
            smalls.append(small)
    if not reg_small.ok:
        return "registration failed", f"cannot compare: {reg_small.reason}"
    dense_fit = None
    if config.dense:
        area_small = np.ones((hs, ws), bool)
        if roi is not None:
            area_small = cv2.resize(roi.astype(np.uint8), (ws, hs), interpolation=cv2.INTER_NEAREST).astype(bool)
        warped_gray, seen_small = warp_to_reference(gray_cur, reg_small.H_cur_ref, (hs, ws))
        dense_fit = refine_dense(gray_ref, warped_gray, valid=area_small & seen_small)
    return Small(refs=smalls[:n], curs=smalls[n:], registration=reg_small, dense_fit=dense_fit)


def cue_maps_small(small: Small, valid, dense_fit, *, gain_sigma_px: float, config: CueConfig):
    """Relief and colour cue maps from photometric stereo at the working resolution, and the compared pixels there."""
    hs, ws = small.refs[0].shape[:2]
    reg_small = small.registration
    refs, normalized = [], []
    # The working-resolution images are not needed after this: dropped as they are converted.
    pairs, small.refs, small.curs = list(zip(small.refs, small.curs)), [], []
    while pairs:
        ref, cur = pairs.pop(0)
        ref, cur = as_float(ref), as_float(cur)
        if dense_fit is not None:
            warped, _ = warp_with_flow(cur, reg_small.H_cur_ref, dense_fit.flow)
        else:
            warped, _ = warp_to_reference(cur, reg_small.H_cur_ref, (hs, ws))
        normalized.append(np.clip(normalize_local_gain(ref, warped, sigma_px=max(gain_sigma_px, 1.0)), 0.0, 1.0))
        refs.append(ref)
    # A working pixel is compared when most of the full pixels it covers are.
    valid_small = cv2.resize(valid.astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA) > 0.5
    release_free_memory()
    cue_maps = relief_colour_cues(
        refs, normalized, valid=valid_small, ambient_index=config.ambient_index, light_dirs=config.light_dirs
    )
    return cue_maps, valid_small


def label_cues_small(cue_maps, valid_small, regions, labels, size_wh, *, smooth_sigma_px, fx, fy) -> None:
    """Relief / colour label per region, the regions mapped down to the cue maps' resolution."""
    ws, hs = size_wh
    labels_small = cv2.resize(labels, (ws, hs), interpolation=cv2.INTER_NEAREST)
    for region in regions:  # a region narrower than a working pixel keeps its centroid pixel
        if not (labels_small == region.id).any():
            cx, cy = region.centroid_xy
            labels_small[min(hs - 1, int((cy + 0.5) / fy)), min(ws - 1, int((cx + 0.5) / fx))] = region.id
    label_regions(
        regions,
        labels_small,
        cue_maps,
        valid=valid_small | (labels_small > 0),
        smooth_sigma_px=max(smooth_sigma_px / max(fx, fy), 0.5),
    )
