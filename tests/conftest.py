"""Shared fixtures and the test selection.

Markers: ``slow`` (a test taking more than about 5 s on an idle machine: long streams,
the emulator, real recordings end to end) and ``hil`` (the firmware as a separate process
driven over a pty or TCP, as a host would).  A plain ``pytest`` runs the fast selection,
``-m "not slow and not hil"``; ``--all`` (or ``CI=true``, or ``SPRINGTRACK_ALL_TESTS=1``,
which ``make test`` sets) runs every test; an explicit ``-m`` wins (CONTRIBUTING.md).

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


FAST = "not slow and not hil"


def pytest_addoption(parser):
    parser.addoption("--all", action="store_true",
                     help="run every test, the slow and hil ones too (make test, CI)")


def run_all(config) -> bool:
    return (config.getoption("--all") or os.environ.get("CI", "").lower() in ("1", "true")
            or os.environ.get("SPRINGTRACK_ALL_TESTS") == "1")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes more than about 5 s on an idle machine")
    config.addinivalue_line("markers", "hil: the firmware as a separate process, driven over "
                                       "a pty or TCP (hardware in the loop)")
    if not config.option.markexpr and not run_all(config):
        config.option.markexpr = FAST


def pytest_report_header(config):
    sel = config.option.markexpr or "every test"
    return f"springtrack selection: {sel} (--all or CI=true: every test; CONTRIBUTING.md)"
