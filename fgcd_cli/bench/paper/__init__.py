"""``fgcd bench paper``: paper 000's experiments in the simulator (entry: :func:`fgcd_cli.bench.paper.main.run`)."""
