"""pyproject.toml: the licence in the SPDX string form and a build backend that reads it.

setuptools deprecates ``license = { text = ... }`` (a warning on every build) and
accepts the SPDX string form from version 77 on.
"""

import re
import tomllib
from pathlib import Path

from packaging.licenses import canonicalize_license_expression

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def _config() -> dict:
    return tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))


def test_license_is_an_spdx_expression():
    license_ = _config()["project"]["license"]
    assert isinstance(license_, str), f"license must be an SPDX string, not {license_!r}"
    assert canonicalize_license_expression(license_) == license_


def test_build_backend_supports_spdx_licenses():
    requires = _config()["build-system"]["requires"]
    setuptools = [r for r in requires if re.match(r"setuptools\b", r)]
    assert len(setuptools) == 1, requires
    match = re.search(r">=\s*(\d+)", setuptools[0])
    assert match and int(match.group(1)) >= 77, f"{setuptools[0]}: the SPDX form needs setuptools>=77"


def test_no_license_classifier_alongside_the_expression():
    # setuptools>=77 refuses "License ::" classifiers next to an SPDX expression.
    classifiers = _config()["project"].get("classifiers", [])
    assert not [c for c in classifiers if c.startswith("License ::")]
