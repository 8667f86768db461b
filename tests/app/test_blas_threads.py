"""Every fgcd command runs BLAS on one thread unless the user sized the pool (app/determinism.py).

Checked in a fresh interpreter per case: the limit is process-wide, and a test process must keep its own.
"""

import json
import os
import subprocess
import sys

import pytest

_PROBE = """
import json, sys
import numpy
from fgcd_cli.cli.app import main
sys.argv = ["fgcd", "--version"]
try:
    main()
except SystemExit:
    pass
from threadpoolctl import threadpool_info
import os
print(json.dumps({"pools": [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"],
                  "env": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""


def _probe(env: dict) -> dict:
    done = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def _environment(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    env.update(extra)
    return env


def test_the_command_line_limits_the_loaded_blas_and_its_children_to_one_thread():
    out = _probe(_environment())
    assert out["pools"] and set(out["pools"]) == {1}
    assert out["env"] == "1"  # a child process (a Dask worker) loads its BLAS with one thread


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="a pool of two needs two cores")
def test_a_pool_the_user_sized_is_left_as_it_is():
    out = _probe(_environment(OPENBLAS_NUM_THREADS="2"))
    assert set(out["pools"]) == {2} and out["env"] == "2"
