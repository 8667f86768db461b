"""Experiment harness: ``fgcd bench NAME`` runs ``fgcd_cli.bench.NAME.run(quick=...)``."""
