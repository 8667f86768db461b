"""A site's whole archive: finding its visits, knowing which analyses are up to date, tracking regions over time.

``discovery.py`` finds campaigns, stations and visits under given roots;
``freshness.py`` decides whether a visit's stored analysis is up to date
(detector version + the inputs' checksums + its products present);
``tracking.py`` follows each change region across a station's visits.
The use cases that run them (on Dask) are :mod:`fgcd_cli.app.archive` and
:mod:`fgcd_cli.app.archive_history`; see docs/archive.md, "One task per visit".
"""
