"""Shared set-up of the driver tests."""

import os

#: The loopback address this test process's fake UR controllers listen on. The controller's ports
#: are fixed (29999, 30003, 30004), so each pytest-xdist worker takes its own address of 127.0.0.0/8
#: (gw0: 127.0.0.1, gw1: 127.0.1.1, ...): two workers' fakes never collide, and a test that expects
#: nobody to answer on its address is not answered by the other worker's fake.
UR_HOST = f"127.0.{int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw') or 0)}.1"
