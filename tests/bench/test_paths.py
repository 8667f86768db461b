"""The benchmarks find the repository and the shared data beside it, wherever their module sits."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_the_bench_paths_name_the_repository_and_the_shared_dataset():
    from fgcd_cli.bench.changes import large, main
    from fgcd_cli.bench.faults import checks
    from fgcd_cli.bench.paths import FGCD_DATASET, REPO_ROOT

    assert REPO_ROOT == REPO and (REPO_ROOT / "fgcd_cli").is_dir()
    assert FGCD_DATASET.resolve() == (REPO / ".." / "shared" / "data" / "fgcd-dataset").resolve()
    assert main.DATASET == FGCD_DATASET and large.DATASET == FGCD_DATASET and checks.ROOT == REPO_ROOT
