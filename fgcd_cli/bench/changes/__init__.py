"""``fgcd bench changes``: change detection on the real FGCD dataset and on simulated pairs (entry: :func:`fgcd_cli.bench.changes.main.run`)."""
