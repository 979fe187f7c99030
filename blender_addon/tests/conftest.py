"""Shared by the add-on's pytest files: the sweptvol binary under test.

SWEPTVOL_BIN names it (scripts/test-all.sh sets it to target/release/sweptvol); by default
target/release/sweptvol in this repository. A missing binary fails the tests that need it when
SWEPTVOL_REQUIRE_BIN=1 (as test-all.sh sets), and otherwise skips them with a warning saying why.
"""

import os
import warnings

import pytest

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


@pytest.fixture
def sweptvol_bin():
    path = os.environ.get("SWEPTVOL_BIN") or os.path.join(REPO, "target", "release", "sweptvol")
    path = os.path.abspath(path)
    if os.path.isfile(path) and os.access(path, os.X_OK):
        return path
    why = (f"no sweptvol binary at {path} (set SWEPTVOL_BIN, or build it: cargo build --release)")
    if os.environ.get("SWEPTVOL_REQUIRE_BIN") == "1":
        pytest.fail(f"{why}; SWEPTVOL_REQUIRE_BIN=1 makes that a failure")
    warnings.warn(f"skipped: {why}", stacklevel=1)
    pytest.skip(why)
