"""``fgcd diff`` on a campaign reports the relocation's own residual estimate (never the simulator's truth)."""

import json

from fgcd_cli.app.visit_logs import relocation_residual_mm


class _Visit:
    def __init__(self, rows):
        self._data = "\n".join(json.dumps(r) for r in rows).encode() if rows is not None else None

    def has(self, name):
        return name == "relocation.jsonl" and self._data is not None

    def bytes(self, name):
        return self._data


def test_residual_is_the_last_rows_estimate_never_the_truth():
    rows = [{"iteration": 1, "offset_mm": 25.1}, {"iteration": 2, "offset_mm": 2.7, "truth": {"pose_err_mm": 0.2}}]
    assert relocation_residual_mm(_Visit(rows)) == 2.7


def test_no_log_or_no_estimate_gives_none():
    assert relocation_residual_mm(_Visit(None)) is None
    assert relocation_residual_mm(_Visit([{"iteration": 1, "truth": {"pose_err_mm": 3.0}}])) is None


class _Manifested(_Visit):
    def __init__(self, rows, relocation):
        super().__init__(rows)
        self.metadata = {"relocation": relocation}


def test_report_row_states_the_runs_residual_with_its_uncertainty():
    from fgcd_cli.app.visit_logs import relocation_residual_text

    stated = {"offset_mm": 0.2736, "sigma_mm": 0.1152, "tolerance_mm": 1.078, "source": "image", "agreement": "agree"}
    rows = [{"iteration": 6, "offset_mm": 0.27, "truth": {"pose_err_mm": 0.44}}]
    text = relocation_residual_text(_Manifested(rows, {"residual": stated}))
    assert text == "0.27 ± 0.12 mm (image estimate; tolerance 1.08 mm; 3D/image: agree)"
    # older visits without a stated residual: the last logged estimate, said to lack its uncertainty
    assert relocation_residual_text(_Manifested(rows, {})) == "0.27 mm (no uncertainty logged)"
    assert relocation_residual_text(_Manifested(None, {})) == "not logged"
