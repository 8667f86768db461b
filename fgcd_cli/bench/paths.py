"""Where the benchmarks find the repository and the shared data beside it (the one home of these paths)."""

from __future__ import annotations

from pathlib import Path

#: The repository root: the folder holding ``fgcd_cli/`` (fgcd children of the fault benches run from here).
REPO_ROOT = Path(__file__).resolve().parents[2]
#: The real FGCD dataset (Feng et al., ICCV 2015), in ``../shared`` beside the repository, never copied.
FGCD_DATASET = REPO_ROOT / ".." / "shared" / "data" / "fgcd-dataset"
#: Real objects under 12 known lights from a fixed camera (photometric-stereo sets), never copied.
MULTILIGHT = REPO_ROOT / ".." / "shared" / "data" / "multilight"
