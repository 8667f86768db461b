"""`fgcd demo` feedback: every step runs under a live progress label, and it counts injected changes
the same way when it announces them and when it scores them (issue 24, items 7 and 12)."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
from rich.console import Console

import fgcd_cli.app.demo as demo_mod
from fgcd_cli.app.demo import DemoConfig, run_demo
from fgcd_cli.cli.demo_cmd import summary_lines
from fgcd_cli.metrics.sim_eval import count_changes_found, score_change_detection


def _truth_ids() -> np.ndarray:
    """Change 1 seen as two pieces, change 2 as one; changes 3 and 4 are out of view."""
    ids = np.zeros((40, 40), np.int32)
    ids[5:10, 5:10] = 1
    ids[5:10, 20:25] = 1
    ids[30:35, 30:35] = 2
    return ids


def test_changes_are_counted_by_identity_not_by_blob():
    ids = _truth_ids()
    found = np.zeros(ids.shape, bool)
    found[6:8, 21:23] = True  # one piece of change 1
    counts = count_changes_found(found, ids, injected=4)
    assert counts == {"injected_changes": 4, "true_changes": 2, "true_changes_found": 1}
    # the blob count the demo printed before ("1 of 3") counted pieces, not changes
    assert score_change_detection(found, ids > 0)["true_changes"] == 3


def _summary(evaluation: dict) -> dict:
    return {
        "campaign": "c",
        "reference": {"cloud_points": 10},
        "relocation": {
            "converged": True,
            "adjustments": 3,
            "session_s": 1.0,
            "final_truth": {"pose_err_mm": 0.5, "afd_px": 0.2},
        },
        "diff": {"regions": 2, "report": "r.html", "evaluation": evaluation},
    }


def test_the_closing_line_counts_the_injected_changes_it_announced():
    evaluation = {"injected_changes": 4, "true_changes": 2, "true_changes_found": 1, "false_regions": 0, "f1": 0.5}
    console = Console(record=True, width=300, color_system=None)
    for line in summary_lines(_summary(evaluation), summary_path="s.json"):
        console.print(line)
    text = console.export_text()
    assert "1 of 4 injected changes found (2 out of the reference's view)" in text
    assert "simulator truth" in text  # truth is named as such


class _Rig:
    def __init__(self):
        self.handles, self.sim, self.info = object(), object(), {"scenario": {}}

    def close(self):
        pass


def test_every_demo_step_runs_under_a_progress_label(tmp_path, monkeypatch):
    """Each long step starts after a progress event: a live display shows it (no silent step)."""
    events: list[tuple[str, str]] = []

    def long_step(name, result):
        def run(*args, **kwargs):
            events.append(("step", name))
            return result(*args, **kwargs) if callable(result) else result

        return run

    def relocate(rig, station, **kwargs):
        with station.new_visit({"lightings": ["front"]}) as w:
            w.add_image("front", np.zeros((4, 4), np.uint8))
            w.commit()
        return SimpleNamespace(
            observation_path="v",
            relocation=SimpleNamespace(
                converged=True, reason="ok", adjustments=1, session_s=1.0, wall_s=1.0, records=[]
            ),
        )

    def capture_ref(rig, station, **kwargs):
        with station.write_reference({"lightings": ["front"]}) as w:
            w.add_image("front", np.zeros((4, 4), np.uint8))
            w.commit()
        return SimpleNamespace(observation_path="r", cloud_points=10, scale=SimpleNamespace(scale=1.0))

    import fgcd_cli.app.capture as capture
    import fgcd_cli.app.diff as usecases
    import fgcd_cli.app.relocate as relocate_uc
    import fgcd_cli.app.rig as rigs
    import fgcd_cli.metrics.sim_eval as sim_eval

    monkeypatch.setattr(demo_mod, "calibrate_sim_intrinsics", long_step("intrinsics", None))
    monkeypatch.setattr(demo_mod, "calibrate_sim_handeye", long_step("hand-eye", {"T_flange_cam": np.eye(4).tolist()}))
    monkeypatch.setattr(rigs, "open_sim_rig", long_step("open rig", lambda *a, **k: _Rig()))
    monkeypatch.setattr(sim_eval, "reference_truth", lambda sim: {})
    monkeypatch.setattr(
        sim_eval.RelocationEvaluator,
        "from_reference",
        classmethod(lambda cls, sim, ref: SimpleNamespace(evaluate=None, summary=None)),
    )
    monkeypatch.setattr(capture, "capture_reference", long_step("capture", capture_ref))
    import fgcd_cli.app.scene_uncertainty as scene_uc

    monkeypatch.setattr(scene_uc, "station_scene_uncertainty", long_step("scene map", None))
    monkeypatch.setattr(relocate_uc, "relocate_and_capture", long_step("relocate", relocate))
    monkeypatch.setattr(usecases, "run_campaign", long_step("diff", {}))

    summary = run_demo(
        tmp_path / "d",
        config=DemoConfig(),
        say=lambda text: events.append(("say", text)),
        on_progress=lambda done, total, label: events.append(("progress", label)),
    )
    assert summary["out"] == str(tmp_path / "d")  # the JSON result names where it wrote (issue 48, item 10)
    assert summary["summary"] == str(tmp_path / "d" / "summary.json")
    steps = [i for i, (kind, _) in enumerate(events) if kind == "step"]
    assert [events[i][1] for i in steps] == [
        "intrinsics",
        "hand-eye",
        "open rig",
        "capture",
        "scene map",
        "open rig",
        "relocate",
        "diff",
    ]
    previous = -1
    for i in steps:
        labels = [text for kind, text in events[previous + 1 : i] if kind == "progress"]
        assert labels, f"step {events[i][1]} starts without a progress label: {events[previous + 1 : i]}"
        previous = i


def test_the_demo_says_where_it_writes_before_any_work(tmp_path, monkeypatch):
    """A non-empty --out gets a timestamped subfolder: named on the first line, before the demo starts
    (issue 48, item 10), and in the JSON result."""
    import json

    from typer.testing import CliRunner

    import fgcd_cli.cli.demo_cmd as demo_cmd
    from fgcd_cli.cli.app import app

    events = []
    (tmp_path / "old-run").mkdir()  # the folder holds an earlier run

    def fake_run(out_dir, **kwargs):
        events.append(("run", str(out_dir)))
        return {
            "out": str(out_dir),
            "campaign": str(out_dir / "campaign"),
            "reference": {"cloud_points": 1},
            "relocation": {"converged": True, "adjustments": 1, "session_s": 1.0},
        }

    monkeypatch.setattr(demo_mod, "run_demo", fake_run)
    monkeypatch.setattr(demo_cmd, "info", lambda text: events.append(("info", text)))
    r = CliRunner().invoke(app, ["demo", "-o", str(tmp_path), "--json"])
    assert r.exit_code == 0, r.output
    (kind, first), (then, nested) = events[0], events[1]
    assert kind == "info" and then == "run"
    assert first == f"writing the demo into {nested} (a new folder: {tmp_path} is not empty)"
    assert Path(nested).parent == tmp_path and Path(nested).name.endswith("Z")
    assert json.loads(r.stdout.strip().splitlines()[-1])["out"] == nested


def test_an_empty_or_new_out_folder_is_used_as_given(tmp_path):
    from fgcd_cli.app.demo import demo_output_dir

    assert demo_output_dir(tmp_path / "new") == (tmp_path / "new", f"writing the demo into {tmp_path / 'new'}")
    assert demo_output_dir(tmp_path)[0] == tmp_path  # empty
