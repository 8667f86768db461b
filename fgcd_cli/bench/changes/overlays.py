"""Overlays of ``fgcd bench changes --overlays``: per real group, the found regions over the reference."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.detect import detect_changes
from fgcd_cli.changes.io import read_image

__all__ = ["write_overlays"]


def write_overlays(folders, scored, options: dict, overlay_dir: Path) -> None:
    """Overlay per group at the deployed constants (``options``): found regions, ground truth outlined in green."""
    from fgcd_cli.report.figures import change_overlay, png_bytes

    overlay_dir.mkdir(parents=True, exist_ok=True)
    for folder, group in zip(folders, scored):
        lightings = group["lightings"]
        ref = [read_image(folder / f"2-{k}.png") for k in lightings]
        cur = [read_image(folder / f"1-{k}.png") for k in lightings]
        truth = cv2.imread(str(folder / "GT.png"), cv2.IMREAD_GRAYSCALE) > 127
        mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
        result = detect_changes(ref, cur, config=DetectionConfig.from_options(**options))
        overlay = change_overlay(
            ref[0], result.labels, result.regions, valid=result.valid, candidates=result.candidates
        )
        contours, _ = cv2.findContours((truth & mask).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(overlay, contours, -1, (0, 255, 0), 1)
        h, w = overlay.shape[:2]
        (overlay_dir / f"changes_{folder.name}.png").write_bytes(
            png_bytes(cv2.resize(overlay, (w // 2, h // 2), interpolation=cv2.INTER_AREA))
        )
        maps = result.cue_maps
        if maps is not None and maps.normals_ref is not None:
            # Reference (pseudo-)normals as RGB = (n + 1) / 2, and the albedo scaled to its 99th percentile.
            normals = np.nan_to_num((maps.normals_ref + 1.0) / 2.0, nan=0.0)
            albedo = np.nan_to_num(maps.albedo_ref, nan=0.0)
            albedo = np.clip(albedo / max(float(np.percentile(albedo, 99)), 1e-9), 0.0, 1.0)
            if albedo.ndim == 2:
                albedo = np.repeat(albedo[:, :, None], 3, axis=2)
            pair = np.concatenate([normals, albedo], axis=1)
            pair = (pair * 255 + 0.5).astype(np.uint8)
            (overlay_dir / f"normals_albedo_{folder.name}.png").write_bytes(
                png_bytes(cv2.resize(pair, (pair.shape[1] // 2, pair.shape[0] // 2), interpolation=cv2.INTER_AREA))
            )
