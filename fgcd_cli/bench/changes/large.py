"""Large-frame benchmark of the tiled change detection (``fgcd bench changes``, 24 MP part).

Field cameras take 20-45 MP frames. No real group of that size with ground truth
exists, so one is **synthesised**: the real group Db-1 of the FGCD dataset
(Feng et al., ICCV 2015; ~700 x 700 px, 7 lightings, observation 2 = reference,
observation 1 = current) is upscaled 7x with ``cv2.INTER_CUBIC`` (~4900 x 4900 =
24 MP), its mask and ground truth with nearest neighbour. The upscaled images
are smoother than a real 24 MP frame (no new detail, no sensor noise at the new
pixel pitch): the timing and the memory are representative, the F1 only says
that the tiled detector still finds the upscaled changes.

The detection runs **in a child process** that reads the PNG files itself, so
the peak resident memory (``ru_maxrss`` of that process) includes the image
loading and nothing of the parent.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

from fgcd_cli.bench.paths import FGCD_DATASET, REPO_ROOT
from fgcd_cli.changes.config import DetectionConfig

DATASET = FGCD_DATASET
GROUP = ("Db", "Db-1")


def synthesise(folder: Path, out: Path, *, factor: int, lightings: list[int]) -> dict:
    """Write the upscaled group to ``out`` (``ref-k.png``, ``cur-k.png``, ``mask.png``, ``GT.png``)."""
    out.mkdir(parents=True, exist_ok=True)
    for k in lightings:
        for obs, name in (("2", "ref"), ("1", "cur")):
            image = cv2.imread(str(folder / f"{obs}-{k}.png"), cv2.IMREAD_COLOR)
            if image is None:
                raise FileNotFoundError(folder / f"{obs}-{k}.png")
            big = cv2.resize(image, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC)
            # Fast PNG compression: the files are temporary.
            cv2.imwrite(str(out / f"{name}-{k}.png"), big, [cv2.IMWRITE_PNG_COMPRESSION, 1])
            shape = big.shape[:2]
            del big
    for name in ("mask.png", "GT.png"):
        small = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(out / name), cv2.resize(small, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST))
    return {"height": shape[0], "width": shape[1]}


def child_main(folder: str, lightings: str, tile_px: int, workers: int) -> None:
    """Entry point of the measured child: load, detect, score; print one JSON line (with its own peak RSS)."""
    import resource

    from fgcd_cli.changes.tiled.inputs import load_images
    from fgcd_cli.changes.tiled.pipeline import detect_changes_tiled
    from fgcd_cli.metrics.change_scores import binary_scores

    root = Path(folder)
    ks = [int(k) for k in lightings.split(",")]
    t0 = time.perf_counter()
    # One pool over all the files: two calls would each end on one file decoding alone.
    images = load_images([root / f"ref-{k}.png" for k in ks] + [root / f"cur-{k}.png" for k in ks])
    ref, cur = images[: len(ks)], images[len(ks) :]
    del images
    mask = cv2.imread(str(root / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    t_load = time.perf_counter() - t0
    stages: list[tuple[str, float]] = []
    result = detect_changes_tiled(
        ref,
        cur,
        roi=mask,
        progress=lambda done, total, label: stages.append((label, time.perf_counter() - t0)),
        config=DetectionConfig.from_options(tile_px=tile_px, workers=workers),
    )
    seconds = time.perf_counter() - t0
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    truth = cv2.imread(str(root / "GT.png"), cv2.IMREAD_GRAYSCALE) > 127
    f1 = binary_scores(result.mask, truth, eval_mask=mask).f1
    first_tile = next((t for label, t in stages if label.startswith("gain pass")), None)
    last_tile = max((t for label, t in stages if "tile" in label), default=None)
    print(
        json.dumps(
            {
                "seconds": seconds,
                "peak_rss_mb": peak_mb,
                "f1": f1,
                "regions": len(result.regions),
                "comparable": result.comparable,
                "reason": result.reason,
                "seconds_loading": t_load,
                "seconds_working_resolution": (stages[0][1] - t_load) if stages else None,
                "seconds_tiles": (last_tile - stages[0][1]) if stages and last_tile else None,
                "seconds_decision_and_cues": (seconds - last_tile) if last_tile else None,
                "first_tile_at": first_tile,
                "tiles": result.settings.get("tiled", {}).get("tiles"),
                "robust_gain_rounds": result.settings.get("robust_gain_rounds"),
            }
        )
    )


def _run_child(folder: Path, lightings: list[int], tile_px: int, workers: int) -> dict:
    code = (
        "import sys; from fgcd_cli.bench.changes.large import child_main; "
        "child_main(sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))"
    )
    cwd = REPO_ROOT
    done = subprocess.run(
        [sys.executable, "-c", code, str(folder), ",".join(map(str, lightings)), str(tile_px), str(workers)],
        capture_output=True,
        text=True,
        cwd=cwd,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(f"tiled detection child failed ({done.returncode}): {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _untiled_f1(folder: Path, lightings: list[int]) -> dict:
    """The untiled detector and the tiled one on the real (small) group: how far tiling moves the result."""
    from fgcd_cli.changes.detect import detect_changes
    from fgcd_cli.changes.tiled.inputs import load_images
    from fgcd_cli.changes.tiled.pipeline import detect_changes_tiled
    from fgcd_cli.metrics.change_scores import binary_scores

    ref = load_images([folder / f"2-{k}.png" for k in lightings])
    cur = load_images([folder / f"1-{k}.png" for k in lightings])
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_GRAYSCALE) > 127
    truth = cv2.imread(str(folder / "GT.png"), cv2.IMREAD_GRAYSCALE) > 127
    plain = detect_changes(ref, cur, roi=mask)
    tiled = detect_changes_tiled(ref, cur, roi=mask, config=DetectionConfig.from_options(tile_px=256))
    return {
        "f1_untiled": binary_scores(plain.mask, truth, eval_mask=mask).f1,
        "f1_tiled_256px": binary_scores(tiled.mask, truth, eval_mask=mask).f1,
        "f1_tiled_vs_untiled": binary_scores(tiled.mask, plain.mask, eval_mask=mask).f1,
    }


def run_large(*, quick: bool, dataset: Path = DATASET, tile_px: int = 2048, workers: int = 2) -> dict:
    """Seconds and peak memory of the tiled detection on a synthesised 24 MP pair (quick: ~12 MP, 3 lightings)."""
    folder = dataset / GROUP[0] / GROUP[1]
    if not (folder / "GT.png").is_file():
        return {"available": False, "reason": f"group {GROUP[1]} not found at {folder.resolve()}"}
    factor = 5 if quick else 7
    lightings = [1, 4, 7] if quick else list(range(1, 8))
    with tempfile.TemporaryDirectory(prefix="fgcd-large-") as tmp:
        size = synthesise(folder, Path(tmp), factor=factor, lightings=lightings)
        child = _run_child(Path(tmp), lightings, tile_px, workers)
    megapixels = size["height"] * size["width"] / 1e6
    small = _untiled_f1(folder, lightings)
    out = {
        "available": True,
        "quick": quick,
        "seconds_per_pair_24mp": child["seconds"],
        "peak_rss_mb_24mp": child["peak_rss_mb"],
        "megapixels": megapixels,
        "lightings": len(lightings),
        "tile_px": tile_px,
        "workers": workers,
        "f1_vs_upscaled_gt": child["f1"],
        "regions": child["regions"],
        "stage_seconds": {
            k: child[k]
            for k in ("seconds_loading", "seconds_working_resolution", "seconds_tiles", "seconds_decision_and_cues")
        },
        "real_group_700px": small,
        "synthesised": f"{GROUP[1]} upscaled {factor}x (cubic), stated as such",
        "measured": "in a child process that loads the PNGs itself; seconds include loading; peak RSS = its ru_maxrss",
    }
    if quick:
        out["note"] = (
            f"quick: {megapixels:.0f} MP and {len(lightings)} lightings, not 24 MP x 7: the "
            "*_24mp keys hold this smaller case"
        )
    return out


if __name__ == "__main__":  # python -m fgcd_cli.bench.changes.large [--quick]
    print(json.dumps(run_large(quick="--quick" in sys.argv), indent=2))
