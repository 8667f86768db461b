"""The change detector's version, recorded with every archived analysis.

Rule: raise :data:`DETECTOR_VERSION` whenever a change to :mod:`fgcd_cli.changes`
(or the diff use case, :mod:`fgcd_cli.app.diff`) can change what a diff writes
for the same inputs; ``fgcd archive analyze`` then re-does every visit analysed
by an older version and skips the others (docs/archive.md, "Up to date").
"""

DETECTOR_VERSION = "2026.12.3"
