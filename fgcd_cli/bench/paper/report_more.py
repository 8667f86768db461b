"""``fgcd bench paper``'s Table 3 (with ACR_w/X), Table 4, Figs. 4, 6, 12 and §5.5, from the run files only.

Like :mod:`fgcd_cli.bench.paper.report`: every number is read from the runs'
JSON; the paper's published values come from :data:`PAPER_MORE`.
"""

from __future__ import annotations

import math
import statistics

from fgcd_cli.bench.paper.plan import FIG4_NOISE, FIG12_VARIANTS, TABLE4_CASES

__all__ = ["PAPER_MORE", "afd_cell", "figures", "fmt", "runs_by", "sections"]

#: Paper 000's Table 3 (total time s, adjustments) and Table 4 (mean AFD px; None: "fail").
PAPER_MORE = {
    "table3": {"rACR": (61.1, 5.3), "ACR_w/X": (256.4, 14.3), "rACR_w/oX": (102.6, 8.1)},
    "table4": {
        "ACR": (12.35, 8.845, None, 4.263, 4.186, 7.069, 16.17, 19.24, 11.74),
        "rACR": (1.375, 1.183, 1.579, 1.372, 1.544, 1.466, 1.789, 1.528, 1.719),
    },
}


def fmt(value, spec: str = "{:.2f}") -> str:
    """A number as a table cell ("–" when missing or not finite)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return spec.format(value)


def runs_by(results: list[dict], experiment: str) -> dict[tuple[str, str], dict]:
    """An experiment's runs by ``(case, label)``."""
    return {(r["case"], r["label"]): r for r in results if r.get("experiment") == experiment}


def afd_cell(run: dict | None) -> str:
    """A run's true AFD, bold when it failed (AFD >= 3 px or paused)."""
    if run is None:
        return "not run"
    text = fmt(run.get("afd_px"))
    if "error" in run:
        return f"**{text}** (paused)"
    return text if run.get("success") else f"**{text}**"


def _mean_std(values) -> tuple[float, float]:
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not xs:
        return math.nan, math.nan
    return statistics.fmean(xs), (statistics.stdev(xs) if len(xs) > 1 else 0.0)


def _table3(results: list[dict], summary: dict) -> list[str]:
    if not (summary.get("acr_handeye_runs") or summary.get("racr_no_handeye_runs")):
        return []
    paper = PAPER_MORE["table3"]
    lines = [
        "### Table 3: with and without the hand-eye (means over the Table 3 cases; rig time at 1.5 s/cm)",
        "",
        "| method | runs | success | mean AFD (px) | adjustments | rig time (s) | paper: time (s) | "
        "paper: adjustments |",
        "|---|---|---|---|---|---|---|---|",
    ]
    t3_cases = {r["case"] for r in results if r.get("experiment") == "table3"}
    base = [
        r
        for r in results
        if r.get("experiment") == "table2" and r["label"] in ("racr", "acr") and r["case"] in t3_cases
    ]
    rows = (
        ("rACR", [r for r in base if r["label"] == "racr"]),
        ("ACR_w/X", [r for r in results if r.get("experiment") == "table3" and r["label"] == "acr-handeye"]),
        ("ACR (X = I)", [r for r in base if r["label"] == "acr"]),
        ("rACR_w/oX", [r for r in results if r.get("experiment") == "table3" and r["label"] == "racr-no-handeye"]),
    )
    for name, runs in rows:
        if not runs:
            continue
        ok = [r for r in runs if "error" not in r]
        p = paper.get(name, (None, None))
        lines.append(
            f"| {name} | {len(runs)} | {sum(bool(r.get('success')) for r in runs)}/{len(runs)} | "
            f"{fmt(_mean_std(r.get('afd_px') for r in runs)[0])} | "
            f"{fmt(_mean_std(r.get('adjustments') for r in ok)[0], '{:.1f}')} | "
            f"{fmt(_mean_std(r.get('session_s') for r in ok)[0], '{:.1f}')} | {fmt(p[0], '{}')} | "
            f"{fmt(p[1], '{}')} |"
        )
    return lines + [""]


def _table4(results: list[dict]) -> list[str]:
    runs = runs_by(results, "table4")
    if not runs:
        return []
    names = [c.name for c in TABLE4_CASES]
    lines = [
        "### Table 4: true AFD (px) under challenging situations (W: weak texture, R: repetitive pattern, "
        "V: highly varied illumination; bold: failure)",
        "",
        "| method | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for label, name in (("acr", "ACR"), ("racr", "rACR")):
        lines.append(f"| {name}, ours | " + " | ".join(afd_cell(runs.get((n, label))) for n in names) + " |")
        lines.append(
            f"| {name}, paper | "
            + " | ".join(fmt(v, "{}") if v is not None else "fail" for v in PAPER_MORE["table4"][name])
            + " |"
        )
    cases = {c.name: c for c in TABLE4_CASES}
    lines += [
        "",
        "Cases: "
        + "; ".join(
            f"{n} {cases[n].scene} ({cases[n].reference_light} → {cases[n].visit_light})"
            for n in names
            if any(k[0] == n for k in runs)
        )
        + ".",
    ]
    return lines + [""]


def _fig4(results: list[dict]) -> list[str]:
    runs = runs_by(results, "fig4")
    if not runs:
        return []
    base = runs_by(results, "pure")
    cases = list(dict.fromkeys(case for case, _ in runs))
    levels = [r for r in FIG4_NOISE if any(lab == f"noise-{r:.2f}" for _, lab in runs)]
    lines = [
        "### Fig. 4: pure rACR (no image stage) with noise on the reference points (σ = r × the cloud's "
        "width); true AFD (px), in brackets the true camera-position error (mm)",
        "",
        "| case | r = 0 | " + " | ".join(f"r = {r:.0%}" for r in levels) + " |",
        "|---|---|" + "---|" * len(levels),
    ]
    for case in cases:
        cells = [base.get((case, "racr-pure"))] + [runs.get((case, f"noise-{r:.2f}")) for r in levels]
        lines.append(
            f"| {case} | "
            + " | ".join(f"{afd_cell(c)} ({fmt((c or {}).get('pose_err_mm'), '{:.1f}')})" for c in cells)
            + " |"
        )
    return lines + [""]


def _fig6(results: list[dict]) -> list[str]:
    runs = runs_by(results, "fig6")
    if not runs:
        return []
    base = runs_by(results, "pure")
    lines = [
        "### Fig. 6: pure rACR with the semi-dense (direct, the paper's DSO) against the sparse (ORB landmarks) "
        "VSE, true AFD (px) and true position error (mm)",
        "",
        "| case | scene | visit light | semi-dense AFD | mm | sparse AFD | mm |",
        "|---|---|---|---|---|---|---|",
    ]
    for (case, _), sparse in runs.items():
        dense = base.get((case, "racr-pure"))
        lines.append(
            f"| {case} | {sparse.get('scene', '')} | {sparse.get('visit_light', '')} | {afd_cell(dense)} | "
            f"{fmt((dense or {}).get('pose_err_mm'), '{:.1f}')} | {afd_cell(sparse)} | "
            f"{fmt(sparse.get('pose_err_mm'), '{:.1f}')} |"
        )
    return lines + [""]


def _fig12(results: list[dict]) -> list[str]:
    runs = runs_by(results, "fig12")
    if not runs:
        return []
    base = runs_by(results, "pure")
    cases = list(dict.fromkeys(case for case, _ in runs))
    variants = [("rACR (α = 0.2)", "racr-pure", base)] + [
        (label, label, runs) for label, _, _ in FIG12_VARIANTS if any(lab == label for _, lab in runs)
    ]
    lines = [
        "### Fig. 12: pure rACR (no image stage), the weight α of Eq. 11 and the ablations (rACR-P: no "
        "keyframe refinement, Eq. 16; -F: no fine alignment; -S: no scale estimate); true AFD (px)",
        "",
        "| variant | " + " | ".join(cases) + " | mean ± std |",
        "|---|" + "---|" * (len(cases) + 1),
    ]
    for name, label, table in variants:
        cells = [table.get((c, label)) for c in cases]
        m, s = _mean_std((c or {}).get("afd_px") for c in cells)
        lines.append(f"| {name} | " + " | ".join(afd_cell(c) for c in cells) + f" | {fmt(m)} ± {fmt(s)} |")
    return lines + [""]


def _s55(results: list[dict]) -> list[str]:
    runs = runs_by(results, "s55")
    if not runs:
        return []
    cases = list(dict.fromkeys(case for case, _ in runs))
    lines = [
        "### §5.5: change detection after each relocation (3 injected changes; pixel F1 against the simulator's truth)",
        "",
        "| case | scene | rACR AFD | rACR F1 | rACR false regions | ACR AFD | ACR F1 | ACR false regions |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for case in cases:
        r, a = runs.get((case, "racr")) or {}, runs.get((case, "acr")) or {}
        lines.append(
            f"| {case} | {(r or a).get('scene', '')} | {fmt(r.get('afd_px'))} | {fmt(r.get('f1'))} | "
            f"{fmt(r.get('false_regions'), '{}')} | {fmt(a.get('afd_px'))} | {fmt(a.get('f1'))} | "
            f"{fmt(a.get('false_regions'), '{}')} |"
        )
    return lines + [""]


def sections(data: dict) -> list[str]:
    """The Markdown lines of these experiments (empty for those without runs)."""
    results, summary = data["runs"], data["summary"]
    return (
        _table3(results, summary) + _table4(results) + _fig4(results) + _fig6(results) + _fig12(results) + _s55(results)
    )


def _plot_runs(ax, runs: list[tuple[float, dict | None]], *, label: str) -> None:
    """One case's true AFD against the swept value; a run that paused (did not converge) is ringed in black."""
    pts = [
        (x, run["afd_px"], not run.get("converged"))
        for x, run in runs
        if run is not None and run.get("afd_px") is not None
    ]
    ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
    paused = [p for p in pts if p[2]]
    ax.scatter(
        [p[0] for p in paused],
        [p[1] for p in paused],
        s=110,
        facecolors="none",
        edgecolors="k",
        linewidths=1.2,
        zorder=3,
    )


def _paused_legend(ax) -> None:
    ax.scatter([], [], s=110, facecolors="none", edgecolors="k", linewidths=1.2, label="paused (not converged)")
    ax.legend(fontsize=7)


def figures(data: dict) -> dict[str, bytes]:
    """Fig. 4 (AFD against r), Fig. 12 (AFD against α; the ablations as bars) and §5.5 (F1 bars)."""
    from fgcd_cli.report.charts import figure_png
    from fgcd_cli.report.mpl import plt

    results, out = data["runs"], {}
    base = runs_by(results, "pure")
    f4 = runs_by(results, "fig4")
    if f4:
        fig, ax = plt.subplots(figsize=(5, 3.2))
        for case in dict.fromkeys(c for c, _ in f4):
            runs = [(0.0, base.get((case, "racr-pure")))] + [(r, f4.get((case, f"noise-{r:.2f}"))) for r in FIG4_NOISE]
            _plot_runs(ax, [(x * 100, run) for x, run in runs], label=case)
        _paused_legend(ax)
        ax.axhline(3.0, color="k", linestyle="--", linewidth=0.8)
        ax.set_yscale("log")
        ax.set_xlabel("noise on the reference points r (% of the cloud's width)")
        ax.set_ylabel("true AFD (px)")
        out["fig4_reference_noise.png"] = figure_png(fig)
    f12 = runs_by(results, "fig12")
    if f12:
        fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(8, 3.2))
        for case in dict.fromkeys(c for c, _ in f12):
            runs = [(0.2, base.get((case, "racr-pure")))] + [
                (a, f12.get((case, label))) for label, a, x in FIG12_VARIANTS if not x
            ]
            _plot_runs(ax_a, sorted(runs, key=lambda xr: xr[0]), label=case)
        _paused_legend(ax_a)
        ax_a.set_xlabel("α (weight of the geometric term)")
        ax_a.set_ylabel("true AFD (px)")
        bars = [("rACR", [r for (c, lab), r in base.items() if lab == "racr-pure" and any(c == k[0] for k in f12)])]
        bars += [(f"rACR-{x}", [r for (_, lab), r in f12.items() if lab == f"no-{x}"]) for x in "PFS"]
        stats = [
            (name, *_mean_std([r.get("afd_px") for r in v]), sum(not r.get("converged") for r in v), len(v))
            for name, v in bars
            if v
        ]
        ax_b.bar([s[0] for s in stats], [s[1] for s in stats], yerr=[s[2] for s in stats], color="#1f5fa8", capsize=3)
        for i, (_, mean, std, n_paused, n) in enumerate(stats):
            if n_paused:  # a mean over paused runs is not an accuracy: say how many
                ax_b.annotate(f"{n_paused}/{n} paused", (i, mean + std), ha="center", va="bottom", fontsize=7)
        ax_b.set_ylabel("true AFD (px), mean ± std")
        out["fig12_alpha_ablations.png"] = figure_png(fig)
    s55 = runs_by(results, "s55")
    if s55:
        cases = list(dict.fromkeys(c for c, _ in s55))
        fig, ax = plt.subplots(figsize=(max(4, 0.6 * len(cases) + 2), 3.2))
        for k, (label, colour) in enumerate((("racr", "#1f5fa8"), ("acr", "#c0504d"))):
            values = [(s55.get((c, label)) or {}).get("f1") or 0.0 for c in cases]
            ax.bar([i + 0.4 * k for i in range(len(cases))], values, width=0.4, color=colour, label=label)
        ax.set_xticks([i + 0.2 for i in range(len(cases))], cases, rotation=60, fontsize=7)
        ax.set_ylabel("change-detection F1")
        ax.set_ylim(0, 1)
        ax.legend(fontsize=7)
        out["s55_change_f1.png"] = figure_png(fig)
    return out
