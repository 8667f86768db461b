"""``fgcd bench faults``: injected field faults against real fgcd processes and emulated controllers (entry: :func:`fgcd_cli.bench.faults.main.run`; docs/hardware.md, Faults)."""
