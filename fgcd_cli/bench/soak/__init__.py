"""``fgcd bench soak``: many consecutive simulated revisits of one station (entry: :func:`fgcd_cli.bench.soak.main.run`)."""
