"""Run a command with stderr through a pipe and report its longest silence (seconds without a line).

    .venv/bin/python scripts/longest_silence.py -- .venv/bin/fgcd demo -o /tmp/demo

Prints each stderr line with its arrival time, then one JSON line: ``{"longest_silence_s", "after", "lines",
"exit"}``. Off a terminal fgcd names the current step again after HEARTBEAT_S (8 s) without output
(cli/progress.py); this measures it on a real command.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time


def main(argv: list[str]) -> int:
    cmd = argv[argv.index("--") + 1 :] if "--" in argv else argv
    if not cmd:
        print("usage: longest_silence.py -- COMMAND...", file=sys.stderr)
        return 2
    t0 = last = time.monotonic()
    longest, after, lines = 0.0, "(start)", 0
    previous = "(start)"
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        now = time.monotonic()
        if now - last > longest:
            longest, after = now - last, previous
        last, previous, lines = now, line.rstrip("\n"), lines + 1
        print(f"{now - t0:8.1f}  {previous}", flush=True)
    code = proc.wait()
    print(json.dumps({"longest_silence_s": round(longest, 1), "after": after, "lines": lines, "exit": code}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
