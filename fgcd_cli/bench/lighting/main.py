"""``fgcd bench lighting``: registration across lightings, real photographs beside the simulator.

Per kind of scene (a painted test block, an outdoor relief, a statue, a small
object under a photometric-stereo light set), the failure rate, the fraction
beyond 3 px and the median corner error of cross-lighting registrations
(:mod:`fgcd_cli.bench.lighting.cross_light`), on the real photographs of
``../shared/data`` and on simulated scenes of the same kind rendered under the
same protocol. The targets (issue "A simulated world as hard as real light"):
per kind, the simulated failure rate and fraction beyond 3 px within 0.10 of
the real ones, the median corner error within a factor 1.5.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np

from fgcd_cli.bench.lighting.cross_light import Matcher, summarise
from fgcd_cli.bench.lighting.photographs import (
    FGCD_KINDS,
    LAMP_MATCHERS,
    MULTILIGHT_KIND,
    fgcd_group_rows,
    multilight_rows,
)
from fgcd_cli.bench.lighting.renders import SIM_SCENES, sim_fgcd_rows, sim_multilight_rows
from fgcd_cli.bench.lighting.sphere import sphere_shading
from fgcd_cli.bench.paths import FGCD_DATASET, MULTILIGHT
from fgcd_drivers.sim.appearance import world_appearance

__all__ = ["RATE_TOLERANCE", "MEDIAN_FACTOR", "run"]

#: The targets: |sim - real| of a rate at most this, and the median corner error within this factor.
RATE_TOLERANCE = 0.10
MEDIAN_FACTOR = 1.5
#: The quick run's real groups: one per FGCD kind, and one multi-light object.
QUICK_GROUPS = ("Db-1", "Dp-1", "Ds-1")
QUICK_OBJECTS = ("buddha",)


def _real(quick: bool, say: Callable) -> tuple[list[dict], list[dict]]:
    """Cross-lighting rows of the real photographs, and one line per group or object."""
    rows, groups = [], []
    if FGCD_DATASET.is_dir():
        for kind_dir in sorted(p for p in FGCD_DATASET.iterdir() if p.is_dir()):
            for group in sorted(p for p in kind_dir.iterdir() if (p / "1-1.png").exists()):
                if quick and group.name not in QUICK_GROUPS:
                    continue
                out = fgcd_group_rows(group, say=say)
                rows += out["rows"] + out.get("lamp_rows", [])
                groups.append({"name": group.name, "kind": FGCD_KINDS.get(kind_dir.name, kind_dir.name), **_brief(out)})
    lights_txt = MULTILIGHT / "lights.txt"
    if lights_txt.exists():
        directions = _directions()
        for obj in sorted(p for p in MULTILIGHT.iterdir() if (p / "light-00.png").exists()):
            if quick and obj.name not in QUICK_OBJECTS:
                continue
            out = multilight_rows(obj, directions, say=say)
            rows += out["rows"]
            groups.append({"name": obj.name, "kind": MULTILIGHT_KIND, **_brief(out)})
    return rows, groups


def _directions() -> np.ndarray:
    """The multi-light set's 12 light directions (``lights.txt``: a count, then x y z per line)."""
    return np.loadtxt(MULTILIGHT / "lights.txt", skiprows=1).reshape(-1, 3)


def _brief(out: dict) -> dict:
    s = summarise([r for r in out["rows"] if r["matcher"] == Matcher.SIFT])
    return {
        "pairs": s.get("pairs", 0),
        "failed": int(round(s.get("fail_rate", 0.0) * s.get("pairs", 0))),
        "median_corner_px": s.get("median_corner_px"),
        "same_light_spread_px": out.get("same_light_spread_px"),
        **({"reason": out["reason"]} if "reason" in out else {}),
    }


def _sim(kinds: list[str], quick: bool, appearance, say: Callable) -> tuple[list[dict], list[dict]]:
    """Cross-lighting rows of the simulated counterparts of ``kinds``."""
    rows, scenes = [], []
    directions = _directions() if (MULTILIGHT / "lights.txt").exists() else None
    for kind in kinds:
        for name in SIM_SCENES.get(kind, ())[: 1 if quick else None]:
            if kind == MULTILIGHT_KIND:
                if directions is None:
                    continue
                out = sim_multilight_rows(name, directions, appearance=appearance, say=say)
            else:
                out = sim_fgcd_rows(kind, name, appearance=appearance, say=say)
            rows += out["rows"]
            scenes.append({"name": name, "kind": kind, **_brief(out)})
    return rows, scenes


def _targets_met(real: dict, sim: dict) -> dict:
    """Whether the simulated figures of one kind are within the targets of the real ones."""
    if not real.get("pairs") or not sim.get("pairs"):
        return {"comparable": False}
    r_med, s_med = real["median_corner_px"], sim["median_corner_px"]
    ratio = s_med / r_med if r_med and np.isfinite(r_med) and np.isfinite(s_med) else float("nan")
    return {
        "comparable": True,
        "fail_rate_gap": abs(sim["fail_rate"] - real["fail_rate"]),
        "over3_rate_gap": abs(sim["over3_rate"] - real["over3_rate"]),
        "median_ratio": ratio,
        "met": bool(
            abs(sim["fail_rate"] - real["fail_rate"]) <= RATE_TOLERANCE
            and abs(sim["over3_rate"] - real["over3_rate"]) <= RATE_TOLERANCE
            and np.isfinite(ratio)
            and 1 / MEDIAN_FACTOR <= ratio <= MEDIAN_FACTOR
        ),
    }


def _flat(prefix: str, s: dict) -> dict:
    keys = ("fail_rate", "over3_rate", "median_corner_px", "over1_rate", "p90_corner_px", "median_inliers")
    return {f"{prefix}_{k}": s.get(k) for k in keys if k in s} | {f"{prefix}_pairs": s.get("pairs", 0)}


def run(*, quick: bool = False, say: Callable[[str], None] = print) -> dict:
    """Run the protocol on the real photographs and their simulated counterparts (the process's world).

    Returns
    -------
    dict
        ``kinds`` (per kind, the SIFT matcher of the issue's protocol: real and simulated summaries and
        whether the targets are met), ``matchers`` (every matcher's summaries, over all kinds and per kind),
        ``groups`` and ``scenes`` (one line each), ``rows`` (every cross pair) and ``summary``
        (``real_fail_rate``, ``real_over3_rate``, ``real_median_corner_px`` and the ``sim_*``
        counterparts over all kinds with SIFT, ``<matcher>_real_*`` / ``<matcher>_sim_*`` for the image
        stage's and the grid matchers, ``real_median_afd_error_px`` (how far ``fgcd afd`` across lightings
        lands from its same-lighting value), ``kinds_met``, and the grey sphere's shading check
        (``sphere_render_rel_rms_median`` with the multi-light camera's linear response,
        ``sphere_field_camera_rel_rms_median`` with gamma 2.2, beside ``sphere_lambert_rel_rms_median``,
        :mod:`fgcd_cli.bench.lighting.sphere`)).
    """
    t0 = time.monotonic()
    real_rows, groups = _real(quick, say)
    kinds = sorted(
        {r["kind"] for r in real_rows} | ({MULTILIGHT_KIND} if (MULTILIGHT / "lights.txt").exists() else set())
    )
    if not kinds:
        kinds = sorted(SIM_SCENES)
    appearance = world_appearance()
    sim_rows, scenes = _sim(kinds, quick, appearance, say)

    def rows_of(rows, kind=None, matcher=Matcher.SIFT, pairing=None):
        """Cross-lighting rows (``pairing`` None) or the lamp's own images' (``"lamp"``)."""
        return [
            r
            for r in rows
            if r["matcher"] == matcher and (kind is None or r["kind"] == kind) and r.get("pairing") == pairing
        ]

    per_kind = {}
    for kind in kinds:
        real, sim = summarise(rows_of(real_rows, kind)), summarise(rows_of(sim_rows, kind))
        per_kind[kind] = {**_flat("real", real), **_flat("sim", sim), **_targets_met(real, sim)}
    matchers = {
        str(m): {
            kind: {
                **_flat("real", summarise(rows_of(real_rows, kind, m))),
                **_flat("sim", summarise(rows_of(sim_rows, kind, m))),
            }
            for kind in [None, *kinds]
        }
        for m in Matcher
    }
    comparable = [k for k, v in per_kind.items() if v.get("comparable")]
    afd_errors = [r["afd_error_px"] for r in real_rows if "afd_error_px" in r]
    summary = {
        **_flat("real", summarise(rows_of(real_rows))),
        **_flat("sim", summarise(rows_of(sim_rows))),
        "real_median_afd_error_px": float(np.nanmedian(afd_errors)) if afd_errors else float("nan"),
        "kinds_met": sum(per_kind[k].get("met", False) for k in comparable),
        "kinds_compared": len(comparable),
    }
    for m in LAMP_MATCHERS:
        # the lamp's own images of the real groups (fgcd_cli/app/lamp_image.py), beside the cross pairs
        summary |= _flat(f"lamp_{m}_real", summarise(rows_of(real_rows, matcher=m, pairing="lamp")))
    for m in Matcher:
        if m == Matcher.SIFT:
            continue
        for side in ("real", "sim"):
            for key in ("fail_rate", "over3_rate", "median_corner_px"):
                summary[f"{m}_{side}_{key}"] = matchers[str(m)][None].get(f"{side}_{key}")
    matchers = {m: {("all" if k is None else k): v for k, v in by_kind.items()} for m, by_kind in matchers.items()}
    sphere = None
    if (MULTILIGHT / "gray" / "mask.png").exists():
        sphere = sphere_shading(MULTILIGHT / "gray", _directions())
        summary["sphere_render_rel_rms_median"] = sphere["render_rel_rms_median"]
        summary["sphere_lambert_rel_rms_median"] = sphere["lambert_rel_rms_median"]
        summary["sphere_field_camera_rel_rms_median"] = sphere["field_camera_rel_rms_median"]
        say(
            f"grey sphere: render {sphere['render_rel_rms_median']:.3f} (linear camera; gamma 2.2: "
            f"{sphere['field_camera_rel_rms_median']:.3f}), ideal Lambert "
            f"{sphere['lambert_rel_rms_median']:.3f} relative RMS (median over the lights)"
        )
    return {
        "settings": {
            "quick": quick,
            "rate_tolerance": RATE_TOLERANCE,
            "median_factor": MEDIAN_FACTOR,
            "world": appearance.name,
        },
        "real_available": bool(real_rows),
        "kinds": per_kind,
        "matchers": matchers,
        "sphere": sphere,
        "groups": groups,
        "scenes": scenes,
        "rows": real_rows + sim_rows,
        "machine": {"cpu_count": os.cpu_count(), "load_avg_1min": os.getloadavg()[0]},
        "seconds": time.monotonic() - t0,
        "summary": summary,
    }
