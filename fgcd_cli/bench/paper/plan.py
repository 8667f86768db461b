"""The runs of ``fgcd bench paper``: which relocations each of paper 000's experiments needs.

Every experiment is a list of :class:`~fgcd_cli.bench.paper.runs.RunSpec`; the
runs an experiment shares with another are not repeated (rACR's default on the
Table 2 cases is also Fig. 12's alpha = 0.2, Fig. 6's semi-dense VSE and Fig.
4's noise-free reference; the report reads them from Table 2). The paper
repeats some runs 3-10 times; here each (case, variant) runs once from its own
seeded start, so spreads come from the cases, not from repetitions.
"""

from __future__ import annotations

from fgcd_cli.bench.paper.runs import RunSpec, World
from fgcd_cli.bench.relocate import CASES, Case
from fgcd_cli.relocation.enums import LoopMode, RelocationMethod

__all__ = ["EXPERIMENTS", "QUICK", "TABLE4_CASES", "plan"]

EXPERIMENTS = ("table2", "table5", "fig7", "table3", "table4", "fig4", "fig6", "fig12", "s55", "revisit")
#: ``--quick``: one or two cases per experiment, sized for <= 30 min on 2 cores (the time: docs/benchmarks.md,
#: "rACR beside the ACR baseline (`fgcd bench paper`)").
QUICK = {
    "cases": ("indoor-2", "outdoor-1"),
    "one_case": ("indoor-2",),
    "fig7_scenes": ("relief_panel",),
    "fig7_clock": (9,),
    "table4": ("W1",),
    "fig12": ("alpha-1.0", "no-S"),
    "fig4": (0.08,),
}
FIG7_REFERENCE = "led:12"
FIG7_OFFSET = (30.0, 3.0)  # mm, deg: the start of the 20 cases' median
#: The paper's S1-3 (Fig. 12, Fig. 4) and S1-5 (Fig. 6): the first indoor cases.
ABLATION_CASES = ("indoor-1", "indoor-2", "indoor-3")
VSE_CASES = ("indoor-1", "indoor-2", "indoor-3", "indoor-4", "indoor-5")
#: Fig. 12a: alpha over [0, 1] (0.2, the default, is Table 2's run); Fig. 12b: the ablations.
FIG12_VARIANTS = tuple((f"alpha-{a:.1f}", a, "") for a in (0.0, 0.4, 0.6, 0.8, 1.0)) + tuple(
    (f"no-{x}", 0.2, x) for x in ("P", "F", "S")
)
#: Fig. 4: reference-point noise as a fraction of the cloud's width (the paper's 1-16 %).
FIG4_NOISE = (0.01, 0.02, 0.04, 0.08, 0.16)
#: Table 4: weak textures (a limewashed wall with about 50 trackable corners in view; W3 lime plaster with
#: none), repetitive patterns (running-bond bricks) and highly varied illuminations (noon sun against the
#: night lamp, opposite raking LEDs). The weak walls' rigs are calibrated on the relief panel.
TABLE4_CASES = (
    Case("W1", "limewash", 40, "front", "led:3", 30, 3),
    Case("W2", "limewash", 41, "front", "led:9", 25, 2.5),
    Case("W3", "plaster", 42, "front", "led:3", 30, 3),
    Case("R1", "bricks", 43, "front", "led:5", 30, 3),
    Case("R2", "bricks", 44, "front", "led:8", 25, 2.5),
    Case("R3", "bricks", 45, "sun-noon", "sun-evening", 30, 3),
    Case("V1", "stele", 46, "sun-noon", "night", 30, 3),
    Case("V2", "statue", 47, "sun-afternoon", "night", 25, 2.5),
    Case("V3", "relief_panel", 48, "led:12", "led:6", 30, 3),
)


#: Scenes too weakly textured for the target-free hand-eye: their rigs are calibrated on this scene.
WEAK_TEXTURE = {"limewash", "plaster"}
CALIBRATION_SCENE = "relief_panel"


def _world(case: Case) -> World:
    return World(
        name=f"{case.scene}-{case.seed}",
        scene=case.scene,
        seed=case.seed,
        calibration_light=case.reference_light,
        calibration_scene=CALIBRATION_SCENE if case.scene in WEAK_TEXTURE else "",
    )


def _spec(experiment: str, case: Case, label: str, variant: dict | None = None) -> RunSpec:
    return RunSpec(
        experiment=experiment,
        case=case.name,
        label=label,
        world=_world(case),
        reference_light=case.reference_light,
        visit_light=case.visit_light,
        offset_mm=case.offset_mm,
        offset_deg=case.offset_deg,
        **(variant or {}),
    )


_RACR, _ACR, _SER = RelocationMethod.RACR, RelocationMethod.ACR, LoopMode.SERIAL
#: Each experiment's variants on a case: label -> RunSpec fields.
CASE_VARIANTS = {
    "table2": {"racr": {}, "acr": {"method": _ACR}},
    "table4": {"racr": {}, "acr": {"method": _ACR}},
    "table5": {"racr-serial": {"mode": _SER}},
    "table3": {"racr-no-handeye": {"no_handeye": True}, "acr-handeye": {"method": _ACR, "acr_handeye": True}},
    "revisit": {"racr-usual": {"guided": False}, "racr-serial-usual": {"mode": _SER, "guided": False}},
    # Figs. 4, 6 and 12 measure the alignment: the paper's pure rACR, without the image stage, beside its own
    # pure baseline ("pure", planned with any of them)
    "pure": {"racr-pure": {"image_stage": False}},
    "fig6": {"racr-sparse": {"vse": "sparse", "image_stage": False}},
    "fig12": {label: {"alpha": a, "ablation": x, "image_stage": False} for label, a, x in FIG12_VARIANTS},
    "fig4": {f"noise-{r:.2f}": {"reference_noise": r, "image_stage": False} for r in FIG4_NOISE},
}
PURE_FOR = ("fig4", "fig6", "fig12")


def _cases_of(experiment: str, *, quick: bool, names: list[str] | None) -> list[Case]:
    """The cases an experiment runs on (``names``: only these, where they belong to it)."""
    if experiment == "table4":
        pool = list(TABLE4_CASES)
        default = [c for c in pool if c.name in QUICK["table4"]] if quick else pool
    else:
        pool = list(CASES)
        own = {"fig6": VSE_CASES, "fig12": ABLATION_CASES, "fig4": ABLATION_CASES, "pure": VSE_CASES}.get(experiment)
        quick_names = (
            QUICK["one_case"]
            if experiment in ("table3", "fig6", "fig12", "fig4", "revisit", "pure")
            else QUICK["cases"]
        )
        default = [c for c in pool if (c.name in quick_names if quick else (own is None or c.name in own))]
    return [c for c in pool if c.name in names] if names else default


def _variants(experiment: str, *, quick: bool) -> dict[str, dict]:
    variants = CASE_VARIANTS[experiment]
    if quick and experiment == "fig12":
        return {k: v for k, v in variants.items() if k in QUICK["fig12"]}
    if quick and experiment == "fig4":
        return {k: v for k, v in variants.items() if v["reference_noise"] in QUICK["fig4"]}
    return variants


def _fig7_runs(scenes: tuple[str, ...], clock: tuple[int, ...]) -> list[RunSpec]:
    """Fig. 7: each indoor scene's world (its first indoor case), reference at 12 o'clock, visit at each hour."""
    runs = []
    for scene in scenes:
        case = next(c for c in CASES if c.scene == scene and c.name.startswith("indoor"))
        for hour in clock:
            sweep = Case(f"{scene}-led{hour}", scene, case.seed, FIG7_REFERENCE, f"led:{hour}", *FIG7_OFFSET)
            runs += [_spec("fig7", sweep, "racr"), _spec("fig7", sweep, "acr", {"method": _ACR})]
    return runs


def plan(*, quick: bool, experiments: tuple[str, ...] = EXPERIMENTS, cases: list[str] | None = None) -> list[RunSpec]:
    """Every relocation of the invocation, worlds grouped so each is set up once (``s55`` adds none:
    it scores the visits of Table 2)."""
    runs: list[RunSpec] = []
    if any(e in experiments for e in PURE_FOR):
        experiments = ("pure", *experiments)
    for experiment in experiments:
        if experiment in CASE_VARIANTS:
            for case in _cases_of(experiment, quick=quick, names=cases):
                runs += [
                    _spec(experiment, case, label, fields)
                    for label, fields in _variants(experiment, quick=quick).items()
                ]
    if "fig7" in experiments:
        indoor = tuple(dict.fromkeys(c.scene for c in CASES if c.name.startswith("indoor")))
        runs += _fig7_runs(
            QUICK["fig7_scenes"] if quick else indoor, QUICK["fig7_clock"] if quick else tuple(range(1, 13))
        )
    order = {name: i for i, name in enumerate(dict.fromkeys(r.world.name for r in runs))}
    return sorted(runs, key=lambda r: order[r.world.name])  # stable: each world's runs keep their order
