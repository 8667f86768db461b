"""Every default the docs state is the code's default: one table of (doc, its words, the defaults they state).

The docs state defaults in their prose ("instead of the 120 s timeout", "(`robust_gain_rounds`, default 1;"),
not in tables of defaults. Each row below quotes such words as a regular expression whose groups hold the
values (matched on the doc with its line breaks and ``**`` emphasis removed), and names the field of the
config object each group is the default of, with how the words read as the field's value (``mm``: millimetres
of a field in metres). A doc reworded or a default changed without the other fails here, naming both. A
default that no doc states has nothing to drift from and is not listed.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fgcd_cli.alignment.fast_config import FastAlignConfig
from fgcd_cli.app.calibrate import HandEyeRequest
from fgcd_cli.app.relocate_request import RelocateRequest
from fgcd_cli.app.revisit import RevisitRequest
from fgcd_cli.app.rig import RigRequest
from fgcd_cli.calibration.handeye.refine import RefineConfig
from fgcd_cli.calibration.handeye.target_free import TargetFreeConfig
from fgcd_cli.calibration.procedure import TargetFreeRunConfig, TargetRunConfig
from fgcd_cli.changes.baseline_iccv import ICCV2015Config
from fgcd_cli.changes.config import DetectionConfig
from fgcd_cli.changes.dense.refine import DenseConfig
from fgcd_cli.changes.significance import AcontrarioConfig
from fgcd_cli.metrics.afd import FdfConfig
from fgcd_cli.relocation.acr.baseline import AcrConfig
from fgcd_cli.relocation.coarse.config import CoarseConfig
from fgcd_cli.relocation.config import RelocationConfig
from fgcd_cli.report.html import ReportContext
from fgcd_cli.vse.ba import OutlierRejectionConfig
from fgcd_cli.vse.semidense import KeyframeDepthConfig
from fgcd_drivers.connect import PlatformSpec
from fgcd_drivers.sim.platform import SimPlatformConfig

DOCS = Path(__file__).resolve().parents[1] / "docs"


# ----------------------------------------------------------------------------- how the docs' words read
def mm(text: str) -> float:
    return float(text) / 1000.0


def cm(text: str) -> float:
    return float(text) / 100.0


def pct(text: str) -> float:
    return float(text) / 100.0


def per_cm(text: str) -> float:
    """Seconds per centimetre, as seconds per metre."""
    return float(text) * 100.0


def thousands(text: str) -> int:
    """ "12k"."""
    return int(text) * 1000


def reciprocal(text: str) -> float:
    return 1.0 / float(text)


def word(text: str) -> int:
    return {"once": 1, "two": 2, "twice": 2, "three": 3}[text]


def floats(text: str) -> tuple[float, ...]:
    return tuple(float(x) for x in text.split(","))


def names(text: str) -> tuple[str, ...]:
    """ "Tsai, Park, Horaud": the solvers' names as the config spells them."""
    return tuple(n.strip().upper() for n in text.split(","))


@dataclass(frozen=True)
class Row:
    """``says`` in ``doc``; ``fields``: per group of ``says``, in order, the field (dotted, ``[i]`` for an item)
    of ``config`` and how its words read (a function of the group's text), or, when ``says`` has no group, the
    field and the value the words mean ("on by default": True)."""

    doc: str
    says: str
    config: Any
    fields: tuple[tuple[str, Any], ...]
    abs_tol: float = 0.0  # the doc rounds the value


def row(doc: str, says: str, config: Any, *fields: tuple[str, Any], abs_tol: float = 0.0) -> Row:
    return Row(doc, says, config, fields, abs_tol)


R, C, D, F = RelocationConfig(), CoarseConfig(), DetectionConfig(), FastAlignConfig()
NUM = float

DOCUMENTED = [
    # relocation.md: the loop
    row("relocation.md", r"`g ≤ η` \(η = ([0-9.e-]+)\)", R, ("eta", NUM)),
    row(
        "relocation.md",
        r"`--max-adjustments` overrides the budget of either method \(default (\d+) for rACR, "
        r"\d+ for ACR\)",
        R,
        ("max_adjustments", int),
    ),
    row(
        "relocation.md",
        r"`--max-adjustments` overrides the budget of either method \(default \d+ for rACR, "
        r"(\d+) for ACR\)",
        AcrConfig(),
        ("max_adjustments", int),
    ),
    row("relocation.md", r"starts at the loop's largest step \((\d+) mm\)", R, ("max_step_m", mm)),
    row("relocation.md", r"the estimated AFD falls below ([0-9.]+) px", R, ("stop_afd_px", NUM)),
    row(
        "relocation.md",
        r"grows beyond ([0-9.]+) × the best so far \+ (\d+) mm \(or \+ (\d+)°\) on (\w+) "
        r"adjustments in a row",
        R,
        ("divergence_factor", NUM),
        ("divergence_margin_mm", NUM),
        ("divergence_margin_deg", NUM),
        ("divergence_patience", word),
    ),
    row(
        "relocation.md",
        r"more than (\d+) mm or (\d+)° from the reference pauses the 3D loop before any motion "
        r"\(`max_offset_m`, `max_offset_deg`\)",
        R,
        ("max_offset_m", mm),
        ("max_offset_deg", NUM),
    ),
    row(
        "relocation.md", r"Final image stage \(`relocation/image/refine.py`, on by default;", R, ("image_refine", True)
    ),
    row(
        "relocation.md",
        r"moves, and repeats \(at most (\d+) times\) until the correction moves the reference image "
        r"by less than ([0-9.]+) px",
        R,
        ("image_refine_steps", int),
        ("image_stop_afd_px", NUM),
    ),
    row("relocation.md", r"It moves only on strong evidence, up to (\d+) times", R, ("image_fallback_steps", int)),
    row(
        "relocation.md",
        r"a run of untrustworthy estimates \((\d+) in a row after at least (\d+) s, instead of the "
        r"(\d+) s timeout\)",
        R,
        ("untrusted_patience", int),
        ("untrusted_min_wait_s", NUM),
        ("estimate_timeout_s", NUM),
    ),
    row("relocation.md", r"fewer than (\d+) cloud points", R, ("min_points", int)),
    row("relocation.md", r"(\d+) estimates in a row flagged as degenerate geometry", R, ("degenerate_patience", int)),
    row(
        "relocation.md",
        r"The 3D estimate's is a stated model, ([0-9.]+) % of the camera distance "
        r"\(`vse_sigma_rel`\)",
        R,
        ("vse_sigma_rel", pct),
    ),
    row("relocation.md", r"`agreement_k` = ([0-9.]+)", R, ("agreement_k", NUM)),
    row("relocation.md", r"`agreement_wait_s` \((\d+) s\)", R, ("agreement_wait_s", NUM)),
    # relocation.md: the revisit's exploration
    row(
        "relocation.md",
        r"A relocation makes (\d+) legs",
        RelocateRequest(config=None, lightings=["front"]),
        ("explore_legs", int),
    ),
    row("relocation.md", r"## A guided exploration \(the default;", RevisitRequest(station="s"), ("guided", True)),
    row(
        "relocation.md",
        r"## A guided exploration \(the default;",
        RelocateRequest(config=None, lightings=["front"]),
        ("guided", True),
    ),
    # relocation.md: the active coarse stage
    row(
        "relocation.md",
        r"more than (\d+) mm or (\d+)° from it, an active coarse stage runs first",
        C,
        ("trigger_m", mm),
        ("trigger_deg", NUM),
    ),
    row("relocation.md", r"in steps of at most (\d+) mm / (\d+)°", C, ("step_m", mm), ("step_deg", NUM)),
    row("relocation.md", r"Within `basin − (\d+)σ` of the reference pose", C, ("k_sigma", NUM)),
    row("relocation.md", r"The basin is the paper's (\d+) cm / (\d+)°", C, ("basin_m", cm), ("basin_deg", NUM)),
    row("relocation.md", r"`σ = sigma_rel · Z` \(([0-9.]+) % of the scene depth", C, ("sigma_rel", pct)),
    row(
        "relocation.md",
        r"verified when the residual is within (\d+) cm / (\d+)° on at least (\d+) % overlap",
        C,
        ("verify_m", cm),
        ("verify_deg", NUM),
        ("min_fitness", pct),
    ),
    row("relocation.md", r"a z-buffer over (\d+)-px bins", C, ("render_stride_px", int)),
    row("relocation.md", r"the camera turns (\d+)° about its centre", C, ("look_deg", NUM)),
    row("relocation.md", r"After (\d+) such views the stage gives up", C, ("max_looks", int)),
    # user-guide.md: the rig a command opens
    row(
        "user-guide.md",
        r"then the default \(driver `sim`, baud (\d+), camera (\d+)\)",
        RigRequest(driver="sim"),
        ("baud", int),
        ("camera_index", int),
    ),
    row("user-guide.md", r"then the default \(driver `sim`, baud (\d+),", PlatformSpec(), ("baud", int)),
    # calibration.md
    row(
        "calibration.md", r"rotated up to `--rotation-deg` \(default (\d+)°\)", TargetRunConfig(), ("rotation_deg", NUM)
    ),
    row(
        "calibration.md",
        r"OpenCV's five solvers \(([A-Za-z, ]+)\) run on the same samples",
        TargetRunConfig(),
        ("methods", names),
    ),
    row(
        "calibration.md",
        r"rotations of `--rotation-deg` \(default (\d+)°\) about each axis",
        TargetFreeRunConfig(),
        ("rotation_deg", NUM),
    ),
    row(
        "calibration.md",
        r"rotations of `--rotation-deg` \(default (\d+)°\) about each axis",
        HandEyeRequest(),
        ("rotation_deg", NUM),
    ),
    row(
        "calibration.md",
        r"translations of up to `--translation-mm` \(default (\d+) mm\)",
        TargetFreeRunConfig(),
        ("translation_m", mm),
    ),
    row(
        "calibration.md",
        r"translations of up to `--translation-mm` \(default (\d+) mm\)",
        HandEyeRequest(),
        ("translation_mm", NUM),
    ),
    row(
        "calibration.md",
        r"from the start pose, in (\d+) mm / (\d+)° steps",
        TargetFreeRunConfig(),
        ("max_step_m", mm),
        ("max_step_deg", NUM),
    ),
    row(
        "calibration.md",
        r"features are matched between each view and the next (\w+)",
        TargetFreeConfig(),
        ("match_window", word),
    ),
    row(
        "calibration.md",
        r"Observations more than (\d+) px off after a first pass are dropped",
        RefineConfig(),
        ("reject_px", NUM),
    ),
    # vse.md
    row(
        "vse.md",
        r"exceeds (\d+) σ of the window's own residual scale \(σ = median norm / 1.1774, clipped to "
        r"\[([0-9.]+), (\d+)\] px\)",
        OutlierRejectionConfig(),
        ("outlier_sigmas", NUM),
        ("outlier_min_px", NUM),
        ("outlier_max_px", NUM),
    ),
    row("vse.md", r"judged afresh each round \(≤ (\d+) rounds\)", OutlierRejectionConfig(), ("max_rounds", int)),
    row(
        "vse.md",
        r"the strongest-gradient pixel of each (\d+)×\d+ cell \(gradient ≥ (\d+) grey levels/px and above "
        r"the local median, at most (\d+)k per keyframe\)",
        KeyframeDepthConfig(),
        ("cell_px", int),
        ("grad_threshold", NUM),
        ("max_points", thousands),
    ),
    row("vse.md", r"points need (\d+) agreeing views", KeyframeDepthConfig(), ("min_views", int)),
    # simulator.md
    row(
        "simulator.md",
        r"Speed: ([0-9.]+) s per cm, (\d+) deg/s, ([0-9.]+) s settling",
        SimPlatformConfig(),
        ("seconds_per_m", per_cm),
        ("rotation_deg_per_s", NUM),
        ("settle_s", NUM),
    ),
    row("simulator.md", r"`timeout_s` \((\d+) s\) gets as far as", SimPlatformConfig(), ("timeout_s", NUM)),
    # change-detection.md: FDF / AFD
    row(
        "change-detection.md",
        r"`fgcd_cli.metrics.afd.compute_fdf` follows the rACR authors: (SIFT)",
        FdfConfig(),
        ("method", str.lower),
    ),
    row(
        "change-detection.md",
        r"SIFT \(OpenCV, (\d+) features\), Lowe ratio ([0-9.]+), RANSAC homography with "
        r"(\d+) px threshold",
        FdfConfig(),
        ("max_features", int),
        ("ratio", NUM),
        ("ransac_px", NUM),
    ),
    row(
        "change-detection.md",
        r"correlates an (\d+)×\d+ grid of (\d+) px patches",
        FdfConfig(),
        ("grid_cells", int),
        ("patch_px", NUM),
    ),
    row("change-detection.md", r"fewer than (\d+) SIFT inliers", FdfConfig(), ("min_inliers", int)),
    # change-detection.md: the detector
    row("change-detection.md", r"Dense parallax refinement \(`dense=True`, default;", D, ("registration.dense", True)),
    row(
        "change-detection.md",
        r"robust local-quadratic fit whose scale \(σ = (\d+) px\)",
        DenseConfig(),
        ("smooth_px", NUM),
        abs_tol=0.5,
    ),
    row("change-detection.md", r"\(flow beyond (\d+) px,", DenseConfig(), ("max_flow_px", NUM)),
    row("change-detection.md", r"local Gaussian means, σ = (\d+) px\) is removed", D, ("score.gain_sigma_px", NUM)),
    row("change-detection.md", r"\(`robust_gain_rounds`, default (\d+);", D, ("score.robust_gain_rounds", int)),
    row("change-detection.md", r"minimized over ±(\d+) px shifts", D, ("score.shift_radius_px", int)),
    row("change-detection.md", r"then smoothed \(σ = (\d+) px\)", D, ("score.smooth_sigma_px", NUM)),
    row("change-detection.md", r"\(`structure_weight`\), off by default", D, ("score.structure_weight", 0.0)),
    row("change-detection.md", r"\(`edge_tolerance_px`, off by default;", D, ("score.edge_tolerance_px", 0)),
    row("change-detection.md", r"3×3 intensity range > (\d+)× its image median", D, ("score.edge_contrast", NUM)),
    row("change-detection.md", r"\(`decision=\"acontrario\"`, default;", D, ("regions.decision", "acontrario")),
    row("change-detection.md", r"below ε = (\d+) per image", D, ("regions.epsilon", NUM)),
    row("change-detection.md", r"below ε = (\d+) per image", AcontrarioConfig(), ("epsilon", NUM)),
    row(
        "change-detection.md",
        r"\(`decision=\"hysteresis\"`, k = (\d+)/(\d+)\)",
        D,
        ("regions.k_high", NUM),
        ("regions.k_low", NUM),
    ),
    row(
        "change-detection.md",
        r"`extent_fraction` \(([0-9.]+)\) of its peak excess",
        D,
        ("regions.extent_fraction", NUM),
    ),
    row(
        "change-detection.md",
        r"`regions.refine_to_local_peak` \((\d+) % of the largest excess within (\d+) px\)",
        D,
        ("regions.edge_fraction", pct),
        ("regions.edge_radius_px", int),
    ),
    row(
        "change-detection.md",
        r"regions of ≤ (\d+) px removed, holes of ≤ (\d+) px filled",
        D,
        ("regions.min_region_px", int),
        ("regions.max_hole_px", int),
    ),
    row("change-detection.md", r"\(`edge_check_px`; off in the library by default", D, ("edge_check.edge_check_px", 0)),
    row(
        "change-detection.md",
        r"a region is \*?set aside\*? when at least (\d+) % of its pixels lie in the "
        r"reference's strong-edge band",
        D,
        ("edge_check.edge_check_band_fraction", pct),
    ),
    row(
        "change-detection.md",
        r"connected components at a ladder of levels from `seed_p` \(([0-9.]+)\) up",
        D,
        ("regions.seed_p", NUM),
    ),
    row(
        "change-detection.md",
        r"connected components at a ladder of levels from `seed_p` \(([0-9.]+)\) up",
        AcontrarioConfig(),
        ("seed_p", NUM),
    ),
    row(
        "change-detection.md",
        r"the distribution is re-estimated without them \(grown by the correlation radius\), "
        r"up to (\w+)",
        AcontrarioConfig(),
        ("null_rounds", word),
    ),
    row("change-detection.md", r"\(`fine_smooth_sigma_px`, σ = (\d+) px", D, ("score.fine_smooth_sigma_px", NUM)),
    row("change-detection.md", r"at a (\d+) px working resolution", D, ("tiling.work_px", int)),
    row("change-detection.md", r"each (\d+) px tile", D, ("tiling.tile_px", int)),
    row("change-detection.md", r"the score averaged down to (\d+) px", D, ("tiling.decision_px", int)),
    row("change-detection.md", r"split into a rank-(\d+) part and a sparse part", ICCV2015Config(), ("rank", int)),
    row("change-detection.md", r"close-ups of the (\d+) strongest regions", ReportContext(), ("max_closeups", int)),
    # alignment.md: fast alignment
    row("alignment.md", r"`tau_T = ([0-9.e-]+)`", F, ("convergence.tau_T", NUM)),
    row("alignment.md", r"`tau_sigma = ([0-9.e-]+)`", F, ("convergence.tau_sigma", NUM)),
    row("alignment.md", r"Rigid step: (sparse) ICP", F, ("rigid.robust", str)),
    row("alignment.md", r"shrink operator \(`p = ([0-9.]+)`\)", F, ("rigid.sparse_p", NUM)),
    row(
        "alignment.md",
        r"\((\d+) × the median correspondence distance, never below (\d+) reference spacings\)",
        F,
        ("rigid.inlier_factor", NUM),
        ("rigid.min_inlier_spacing", NUM),
    ),
    row("alignment.md", r"also within (\d+) × their median residual", F, ("scale.trim_factor", NUM)),
    row(
        "alignment.md",
        r"Each step changes the scale by at most (\d+) %, and a run by at most (\d+) %",
        F,
        ("scale.max_step", pct),
        ("scale.max_drift", pct),
    ),
    row(
        "alignment.md",
        r"Coarse to fine: (\d+) points with unbounded correspondences and the point-to-point metric "
        r"\(wide basin\), then (\d+) points within (\d+) % of the width, then (\d+) points within (\d+) % of the "
        r"width",
        F,
        ("levels.points[0]", int),
        ("levels.points[1]", int),
        ("levels.radius_rel[1]", pct),
        ("levels.points[2]", int),
        ("levels.radius_rel[2]", pct),
    ),
    row("alignment.md", r"median distance above (\d+) % of the width", F, ("warm.rel", pct)),
    row("alignment.md", r"scored by the (median) nearest-neighbour distance", F, ("cold.search_score", str)),
    row(
        "alignment.md",
        r"the prior shifted by −(\d+)…\d+ steps of (\d+) % of the width",
        F,
        ("cold.shift_steps", int),
        ("cold.shift_rel", pct),
    ),
    row(
        "alignment.md",
        r"followed by (\d+) iterations of rigid point-to-plane ICP on (\d+) points",
        F,
        ("cold.shift_iterations", int),
        ("cold.shift_points", int),
    ),
    row("alignment.md", r"`init × \{([0-9., ]+)\}`", F, ("cold.scale_candidates", floats)),
    row("alignment.md", r"up to (\w+) parabolas", F, ("cold.scale_refinements", word)),
    row(
        "alignment.md",
        r"moved the scale by at most (\d+) % \(`warm_check_scale_change`\)",
        F,
        ("warm.check_scale_change", pct),
    ),
    row(
        "alignment.md",
        r"more than (\d+) % \(`warm_max_scale_change`, was \d+ %\) or the rotation by more than (\d+)°",
        F,
        ("warm.max_scale_change", pct),
        ("warm.max_rotation_deg", NUM),
    ),
    row(
        "alignment.md",
        r"the result's scale × \(1 ± (\d+) %\), each refitted rigidly \((\d+) iterations at the "
        r"finest level\), must not have a median residual more than (\d+) % lower",
        F,
        ("minimum_check.step", pct),
        ("minimum_check.iterations", int),
        ("minimum_check.margin", pct),
    ),
    row(
        "alignment.md",
        r"moves the points by less than ([0-9.]+) % of the working inlier distance",
        F,
        ("convergence.stall_rel", pct),
    ),
    # alignment.md: health
    row(
        "alignment.md",
        r"must be ≥ (\d+) %. The threshold is the largest of (\d+) % of the reference width, (\d+) × "
        r"the two clouds' combined noise",
        F,
        ("health.min_inlier_ratio", pct),
        ("health.inlier_rel", pct),
        ("health.inlier_noise_factor", NUM),
    ),
    row(
        "alignment.md",
        r"current points within (\d+) % of the width \(at least twice the inlier threshold\); must be "
        r"≥ (\d+) %",
        F,
        ("health.overlap_rel", pct),
        ("health.min_overlap", pct),
    ),
    row(
        "alignment.md",
        r"Below `max\(([0-9.e-]+), (\d+) × \(roughness / radius\)²\)`",
        F,
        ("health.min_condition_ratio", NUM),
        ("health.condition_noise_factor", NUM),
    ),
    row(
        "alignment.md",
        r"along each of its \(up to (\d+)\) weakest directions, by a similarity that moves the matched "
        r"points by (\d+) % of the reference width",
        F,
        ("probe.directions", int),
        ("probe.rel", pct),
    ),
    row(
        "alignment.md",
        r"the last ICP level runs again from there \((\d+) points, (\d+) iterations\)",
        F,
        ("probe.points", int),
        ("probe.iterations", int),
    ),
    row(
        "alignment.md",
        r"above ([0-9.]+) in any direction the geometry is degenerate",
        F,
        ("probe.return_fraction", NUM),
    ),
    row(
        "alignment.md",
        r"the scale must stay within \[1/([0-9.]+), ([0-9.]+)\] of the prior",
        F,
        ("health.scale_bounds[0]", reciprocal),
        ("health.scale_bounds[1]", NUM),
    ),
]


def _text(doc: str) -> str:
    """The doc as one line: line breaks and runs of spaces are one space, ``**`` emphasis is gone."""
    return re.sub(r"\s+", " ", (DOCS / doc).read_text(encoding="utf-8").replace("**", ""))


def _field(config: Any, path: str) -> Any:
    value = config
    for part in path.split("."):
        name, *index = re.fullmatch(r"(\w+)((?:\[\d+\])*)", part).groups()
        value = getattr(value, name)
        for i in re.findall(r"\[(\d+)\]", index[0]):
            value = value[int(i)]
    return value


def _same(default: Any, documented: Any, abs_tol: float) -> bool:
    if isinstance(default, tuple) and isinstance(documented, tuple):
        return len(default) == len(documented) and all(_same(a, b, abs_tol) for a, b in zip(default, documented))
    if isinstance(default, (int, float)) and not isinstance(default, bool) and isinstance(documented, (int, float)):
        return math.isclose(default, documented, rel_tol=1e-9, abs_tol=abs_tol)
    return default == documented and type(default == documented) is bool


def test_each_documented_default_is_the_codes():
    texts = {doc: _text(doc) for doc in {r.doc for r in DOCUMENTED}}
    drifted = []
    for r in DOCUMENTED:
        found = re.search(r.says, texts[r.doc])
        if found is None:
            drifted.append(f"docs/{r.doc} no longer says /{r.says}/ ({type(r.config).__name__})")
            continue
        groups = found.groups()
        assert len(groups) == len(r.fields) or (not groups and not any(callable(v) for _, v in r.fields)), r.says
        for k, (path, reads) in enumerate(r.fields):
            documented = reads(groups[k]) if groups else reads
            default = _field(r.config, path)
            if not _same(default, documented, r.abs_tol):
                drifted.append(
                    f"{type(r.config).__name__}.{path} = {default!r}, docs/{r.doc} says {documented!r} "
                    f"({found.group(0)!r})"
                )
    assert not drifted, "\n".join(drifted)
