"""fgcd: fine-grained change detection of cultural heritage with active camera relocalization."""

__version__ = "0.1.0"
