"""Former home of the diff and report use cases, kept importable: they are :mod:`fgcd_cli.app.diff` and :mod:`fgcd_cli.app.report`."""

from fgcd_cli.app.diff import (  # noqa: F401 - re-exports
    EDGE_CHECK_PX,
    LARGE_FRAME_PX,
    BareDiffRequest,
    CampaignDiffRequest,
    measure_fdf,
    relocation_log_rows,
    relocation_residual_mm,
    relocation_residual_text,
    run_bare,
    run_campaign,
)
from fgcd_cli.app.report import station_history  # noqa: F401
