"""The commands the README's tour shows are run, so the docs cannot rot.

Every line starting with `.venv/bin/springtrack` in a fenced block of README.md runs in a
temporary folder (the tour's own files are made by its first commands). The firmware /
hostctl lines need a running firmware on a pty; tests/test_hostctl_hil.py runs the same
verbs against a real firmware-sim process.
"""
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def tour_commands():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```\n(.*?)```", text, re.S)
    cmds = []
    for b in blocks:
        for line in b.splitlines():
            line = line.split("#")[0].strip()
            if line.startswith(".venv/bin/springtrack"):
                cmds.append(line)
    return cmds


def test_readme_has_the_two_setup_commands():
    text = (ROOT / "README.md").read_text()
    quick = text.split("## Quick start", 1)[1].split("##", 1)[0]
    assert "make demo" in quick and "make test" in quick


def test_readme_tour_commands_run(tmp_path, data_file):
    data_dir = data_file("evt3_sample.raw").parent
    cmds = tour_commands()
    assert len(cmds) >= 5
    for line in cmds:
        argv = shlex.split(line)
        argv[0] = str(BIN / Path(argv[0]).name)
        argv = [a.replace("../shared/data", str(data_dir)) for a in argv]
        stdout = None
        if ">" in argv:                               # `cmd > file`
            k = argv.index(">")
            stdout = open(tmp_path / argv[k + 1], "w")
            argv = argv[:k]
        r = subprocess.run(argv, cwd=tmp_path, stdout=stdout or subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True, timeout=300,
                           env={**os.environ, "MPLBACKEND": "Agg"})
        assert r.returncode == 0, f"{line}\n{r.stderr}"
    assert (tmp_path / "gp.gif").stat().st_size > 0
    assert (tmp_path / "face.toml").read_text().startswith('name = "face26"')
