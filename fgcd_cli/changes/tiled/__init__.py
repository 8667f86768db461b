"""Bounded-memory, full-resolution change detection for large frames, tile by tile (entry: :func:`fgcd_cli.changes.tiled.pipeline.detect_changes_tiled`)."""
