"""Every fuzz target of tests/support/fuzz_targets.py (event decoders, file detection, link
frames and payloads, model and parameter TOML) under atheris for a few seconds, each in
its own process (tests/support/atheris_run.py): a crash, an exception other than the
parser's clean error, an input over 10 s or 2 GiB fails the test with libFuzzer's report
(the input is kept in the test's temporary directory).  The long run is
benchmarks/fuzz_atheris.py (results in docs/formats.md)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from support import REPO
from support.fuzz_targets import TARGETS

pytest.importorskip("atheris", reason="pip install 'springtrack[fuzz]' (make test installs it)")
pytestmark = pytest.mark.slow

SECONDS = 3


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_fuzz_target_finds_nothing(name, tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "tests" / "support" / "atheris_run.py"), name,
                        f"-max_total_time={SECONDS}", "-timeout=10", "-rss_limit_mb=2048",
                        f"-artifact_prefix={tmp_path}/"],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-4000:]
    assert "Done " in r.stderr and " runs in " in r.stderr, r.stderr[-2000:]
