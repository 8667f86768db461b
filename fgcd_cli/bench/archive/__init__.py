"""``fgcd bench archive``: the archive analysis at scale on Dask (entry: :func:`fgcd_cli.bench.archive.main.run`)."""
