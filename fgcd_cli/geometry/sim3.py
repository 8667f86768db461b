"""Similarity transforms Sim(3): re-exported from :mod:`fgcd_core.sim3`, where they live."""

from fgcd_core.sim3 import *  # noqa: F401,F403
from fgcd_core.sim3 import Sim3, __all__, umeyama  # noqa: F401
