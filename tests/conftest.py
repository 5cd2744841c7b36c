"""Shared fixtures.

``data_file(name)``: path of a real recording in $SPRINGTRACK_DATA (default
../shared/data from the repository root).  A missing file skips the test, unless
SPRINGTRACK_REQUIRE_DATA=1, in which case it fails.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def data_dir() -> Path:
    return Path(os.environ.get("SPRINGTRACK_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def data_file():
    def get(name: str) -> Path:
        path = data_dir() / name
        if not path.is_file():
            msg = f"real-data file {path} not found (set SPRINGTRACK_DATA)"
            if os.environ.get("SPRINGTRACK_REQUIRE_DATA") == "1":
                pytest.fail(msg + " and SPRINGTRACK_REQUIRE_DATA=1")
            pytest.skip(msg)
        return path
    return get
