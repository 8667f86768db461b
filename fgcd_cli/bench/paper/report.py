"""``fgcd bench paper``'s tables (``<out>/paper.md``) and figures (``<out>/*.png``), built from the run files only.

Nothing here is typed by hand: every number is read from the runs' JSON, and
the paper's published figures come from :data:`fgcd_cli.bench.paper.main.PAPER`.
"""

from __future__ import annotations

import math
from pathlib import Path

from fgcd_cli.bench.paper.report_more import afd_cell, fmt, runs_by
from fgcd_cli.bench.paper.report_more import figures as more_figures
from fgcd_cli.bench.paper.report_more import sections as more_sections
from fgcd_cli.campaign.atomic import atomic_write_bytes, atomic_write_text

__all__ = ["markdown", "write_report"]


def _table2(results: list[dict]) -> list[str]:
    runs = runs_by(results, "table2")
    cases = list(dict.fromkeys(case for case, _ in runs))
    lines = [
        "### Table 2: true AFD (px) per case, rACR vs ACR (bold: failure, AFD ≥ 3 px or paused)",
        "",
        "| case | scene | reference → visit light | rACR AFD | rACR error mm | rACR adj. | rACR rig s | ACR AFD | "
        "ACR error mm | ACR adj. | ACR rig s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for case in cases:
        r, a = runs.get((case, "racr")), runs.get((case, "acr"))
        any_run = r or a
        lines.append(
            f"| {case} | {any_run.get('scene', '')} | {any_run.get('reference_light', '')} → "
            f"{any_run.get('visit_light', '')} | {afd_cell(r)} | {fmt((r or {}).get('pose_err_mm'), '{:.1f}')} | "
            f"{fmt((r or {}).get('adjustments'), '{}')} | {fmt((r or {}).get('session_s'), '{:.1f}')} | "
            f"{afd_cell(a)} | {fmt((a or {}).get('pose_err_mm'), '{:.1f}')} | "
            f"{fmt((a or {}).get('adjustments'), '{}')} | {fmt((a or {}).get('session_s'), '{:.1f}')} |"
        )
    return lines


def _summary_table(summary: dict, paper: dict) -> list[str]:
    s = summary
    n_r, n_a = s.get("racr_runs", 0), s.get("acr_runs", 0)
    ok_r = round(s.get("racr_success_rate", math.nan) * n_r) if n_r else 0
    ok_a = round(s.get("acr_success_rate", math.nan) * n_a) if n_a else 0
    return [
        "### Side by side with the paper (paper 000, Tables 2, 3, 5)",
        "",
        "| | success | mean AFD (px) | adjustments | rig time (s) | of which platform (s) |",
        "|---|---|---|---|---|---|",
        f"| rACR, ours | {ok_r}/{n_r} | {fmt(s.get('racr_mean_afd_px'))} | {fmt(s.get('racr_mean_iterations'), '{:.1f}')} | "
        f"{fmt(s.get('racr_mean_rig_s'), '{:.1f}')} | {fmt(s.get('racr_mean_platform_s'), '{:.1f}')} |",
        f"| rACR, paper | {paper['racr_success']} | {paper['racr_mean_afd_px']} | {paper['racr_mean_iterations']} | "
        f"{paper['racr_mean_rig_s']} | – |",
        f"| ACR, ours | {ok_a}/{n_a} | {fmt(s.get('acr_mean_afd_px'))} | {fmt(s.get('acr_mean_iterations'), '{:.1f}')} | "
        f"{fmt(s.get('acr_mean_rig_s'), '{:.1f}')} | {fmt(s.get('acr_mean_platform_s'), '{:.1f}')} |",
        f"| ACR, paper | {paper['acr_success']} | {paper['acr_mean_afd_px']} | {paper['acr_mean_iterations']} | "
        f"{paper['acr_mean_rig_s']} | – |",
        "",
    ]


VARIANTS = (
    ("racr", "rACR, parallel (Table 2)"),
    ("acr", "ACR (Table 2)"),
    ("racr_serial", "rACR, serial (Table 5)"),
    ("racr_no_handeye", "rACR, X = I (Table 3)"),
    ("acr_handeye", "ACR with the hand-eye (Table 3, ACR_w/X)"),
    ("racr_usual", "rACR, parallel, usual 3-leg exploration"),
    ("racr_serial_usual", "rACR, serial, usual 3-leg exploration"),
    ("table4_racr", "rACR (Table 4)"),
    ("table4_acr", "ACR (Table 4)"),
    ("fig6_sparse", "rACR, sparse VSE (Fig. 6)"),
)


def _variants_table(summary: dict) -> list[str]:
    """Every variant that ran: success, AFD, adjustments, rig time and the platform's share of it."""
    lines = [
        "### Every variant (means over its runs; rig time at the paper's 1.5 s/cm)",
        "",
        "| variant | runs | success | mean AFD (px) | mean / max error (mm) | adjustments | rig time (s) | platform (s) "
        "| platform share |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for key, name in VARIANTS:
        n = summary.get(f"{key}_runs", 0)
        if not n:
            continue
        rig, plat = summary.get(f"{key}_mean_rig_s"), summary.get(f"{key}_mean_platform_s")
        share = plat / rig if rig and plat is not None and rig > 0 else None
        lines.append(
            f"| {name} | {n} | {fmt(summary.get(f'{key}_success_rate'), '{:.0%}')} | "
            f"{fmt(summary.get(f'{key}_mean_afd_px'))} | {fmt(summary.get(f'{key}_mean_pose_err_mm'), '{:.1f}')} / "
            f"{fmt(summary.get(f'{key}_max_pose_err_mm'), '{:.1f}')} | {fmt(summary.get(f'{key}_mean_iterations'), '{:.1f}')} | "
            f"{fmt(rig, '{:.1f}')} | {fmt(plat, '{:.1f}')} | {fmt(share, '{:.0%}')} |"
        )
    return lines + [""]


def _table5(summary: dict, paper: dict) -> list[str]:
    s = summary
    if not s.get("racr_serial_runs"):
        return []
    return [
        "### Table 5: serial vs parallel rACR (rig time, same cases)",
        "",
        "| | parallel (s) | serial (s) | serial / parallel |",
        "|---|---|---|---|",
        f"| ours ({s['racr_serial_runs']} cases) | {fmt(s['racr_serial_mean_rig_s'] / s['parallel_over_serial_speedup'], '{:.1f}') if s.get('parallel_over_serial_speedup') else '–'} | "
        f"{fmt(s.get('racr_serial_mean_rig_s'), '{:.1f}')} | {fmt(s.get('parallel_over_serial_speedup'))} |",
        f"| paper | {paper['parallel_rig_s']} | {paper['serial_rig_s']} | "
        f"{paper['serial_rig_s'] / paper['parallel_rig_s']:.2f} |",
        "",
    ]


def _fig7(results: list[dict]) -> list[str]:
    runs = runs_by(results, "fig7")
    if not runs:
        return []
    scenes = list(dict.fromkeys(case.rsplit("-led", 1)[0] for case, _ in runs))
    hours = sorted({int(case.rsplit("-led", 1)[1]) for case, _ in runs})
    lines = [
        "### Fig. 7: true AFD (px), reference under the LED at 12 o'clock, visit at each hour (rACR / ACR; "
        "true camera-position error in mm in brackets)",
        "",
        "| scene | " + " | ".join(f"{h} o'clock" for h in hours) + " |",
        "|---|" + "---|" * len(hours),
    ]
    for scene in scenes:
        cells = [
            " / ".join(
                f"{afd_cell(runs.get((f'{scene}-led{h}', m)))} "
                f"({fmt((runs.get((f'{scene}-led{h}', m)) or {}).get('pose_err_mm'), '{:.1f}')})"
                for m in ("racr", "acr")
            )
            for h in hours
        ]
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    return lines + [""]


def markdown(data: dict) -> str:
    """The tables of ``<out>/paper.md``."""
    results, summary = data["runs"], data["summary"]
    lines = ["## fgcd bench paper", ""] + _summary_table(summary, data["paper"]) + _table2(results) + [""]
    lines += _table5(summary, data["paper"]) + _variants_table(summary) + _fig7(results)
    lines += more_sections(data)
    errors = [r for r in results if "error" in r]
    if errors:
        lines += (
            ["### Runs that paused", ""]
            + [f"- {r['experiment']} {r['case']} {r['label']}: {r['error']}" for r in errors]
            + [""]
        )
    return "\n".join(lines) + "\n"


def _figures(data: dict) -> dict[str, bytes]:
    """Table 2 as bars per case, Fig. 7 as AFD against the LED hour (log scale: AFDs span 0.1-100 px)."""
    from fgcd_cli.report.charts import figure_png
    from fgcd_cli.report.mpl import plt

    out = {}
    t2 = runs_by(data["runs"], "table2")
    cases = list(dict.fromkeys(case for case, _ in t2))
    if cases:
        fig, ax = plt.subplots(figsize=(max(5, 0.5 * len(cases) + 2), 3.2))
        for k, (label, colour) in enumerate((("racr", "#1f5fa8"), ("acr", "#c0504d"))):
            values = [(t2.get((c, label)) or {}).get("afd_px") or math.nan for c in cases]
            ax.bar([i + 0.4 * k for i in range(len(cases))], values, width=0.4, color=colour, label=label)
        ax.axhline(3.0, color="k", linestyle="--", linewidth=0.8)
        ax.set_xticks([i + 0.2 for i in range(len(cases))], cases, rotation=60, fontsize=7)
        ax.set_yscale("log")
        ax.set_ylabel("true AFD (px)")
        ax.legend(fontsize=7)
        out["table2_afd.png"] = figure_png(fig)
    f7 = runs_by(data["runs"], "fig7")
    if f7:
        fig, ax = plt.subplots(figsize=(5, 3.2))
        for label, colour in (("racr", "#1f5fa8"), ("acr", "#c0504d")):
            pts = sorted(
                (int(c.rsplit("-led", 1)[1]), r.get("afd_px") or math.nan) for (c, lab), r in f7.items() if lab == label
            )
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o", color=colour, label=label, alpha=0.7)
        ax.axhline(3.0, color="k", linestyle="--", linewidth=0.8)
        ax.set_yscale("log")
        ax.set_xlabel("LED position of the visit (o'clock; reference at 12)")
        ax.set_ylabel("true AFD (px)")
        ax.legend(fontsize=7)
        out["fig7_led_sweep.png"] = figure_png(fig)
    return out


def write_report(data: dict, out: Path) -> None:
    """Write ``paper.md``, the figures and ``summary.json`` into ``out`` (atomically)."""
    import json

    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "paper.md", markdown(data))
    for name, png in {**_figures(data), **more_figures(data)}.items():
        atomic_write_bytes(out / name, png)
    atomic_write_text(
        out / "summary.json",
        json.dumps({"summary": data["summary"], "paper": data["paper"], "targets": data["targets"]}, indent=1),
    )
