"""Which packages the wheel holds; the metadata is in pyproject.toml.

The design card fixes a top-level ``drivers/`` folder, but ``drivers`` is too
generic a name to install into site-packages: the folder installs as
``fgcd_drivers`` (a ``package_dir`` mapping, which pyproject's static
``packages.find`` cannot express). Builds write their intermediate ``build/``
and ``*.egg-info`` into a temporary folder, not into the source tree.
"""

import tempfile

from setuptools import find_packages, setup

_OUT_OF_TREE = tempfile.mkdtemp(prefix="fgcd-build-")
_DRIVERS = ["fgcd_drivers" + name[len("drivers") :] for name in find_packages(include=["drivers", "drivers.*"])]

setup(
    packages=find_packages(include=["fgcd_cli", "fgcd_cli.*", "fgcd_core", "fgcd_core.*"]) + _DRIVERS,
    package_dir={"fgcd_drivers": "drivers"},
    options={"build": {"build_base": f"{_OUT_OF_TREE}/build"}, "egg_info": {"egg_base": _OUT_OF_TREE}},
)
