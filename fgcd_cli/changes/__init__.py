"""Fine-grained change detection between a reference and a current observation.

Everything is expressed in the **reference image's frame**. The entry point is
:func:`fgcd_cli.changes.detect.detect_changes`; its options are a
:class:`fgcd_cli.changes.config.DetectionConfig`.
"""
