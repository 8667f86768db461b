"""``fgcd bench align`` is registered and its benchmark module exposes ``run``."""

from __future__ import annotations

from typer.testing import CliRunner

from fgcd_cli.cli.app import app


def test_bench_align_is_registered():
    result = CliRunner().invoke(app, ["bench", "align", "--help"])
    assert result.exit_code == 0
    assert "--quick" in result.output and "--json" in result.output


def test_bench_module_has_run():
    from fgcd_cli.bench import align

    assert callable(align.run)
