"""``fgcd bench lighting``: paper 000's Table 1 protocol on real photographs and their simulated counterparts (entry: :func:`fgcd_cli.bench.lighting.main.run`)."""
