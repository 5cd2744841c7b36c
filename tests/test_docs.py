"""The commands the README's tour shows are run, so the docs cannot rot.

Every line starting with `.venv/bin/springtrack` in a fenced block of README.md runs in a
temporary folder (the tour's own files are made by its first commands). The firmware /
hostctl lines need a running firmware on a pty; tests/test_hostctl/test_hostctl_hil.py runs the same
verbs against a real firmware-sim process.
"""
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from support import REPO

ROOT = REPO
BIN = Path(sys.executable).parent


def _device_block(b: str) -> bool:
    """A block that starts a firmware: its lines run against it (the device test)."""
    return any(line.strip().startswith(".venv/bin/firmware-sim") for line in b.splitlines())


def tour_commands():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
    cmds = []
    for b in blocks:
        if _device_block(b):
            continue
        for line in b.splitlines():
            line = line.split("#")[0].strip()
            if line.startswith(".venv/bin/springtrack") or line.startswith("mkdir "):
                cmds.append(line)
    return cmds


def test_readme_has_the_two_setup_commands():
    text = (ROOT / "README.md").read_text()
    quick = text.split("## Quick start", 1)[1].split("##", 1)[0]
    assert "make demo" in quick and "make test" in quick


@pytest.mark.slow
def test_readme_tour_commands_run(tmp_path, data_file):
    data_dir = data_file("evt3_sample.raw").parent
    cmds = tour_commands()
    assert len(cmds) >= 5
    for line in cmds:
        argv = shlex.split(line)
        if argv[0] != "mkdir":
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
    assert (tmp_path / "scratch" / "gp.gif").stat().st_size > 0     # the tour writes there
    # (the README's Python example runs in test_python_snippets_run)
    assert (tmp_path / "scratch" / "face.toml").read_text().startswith('name = "face26"')


def block_lines(path: Path, prefixes) -> list[str]:
    text = path.read_text()
    out = []
    for b in re.findall(r"```[a-z]*\n(.*?)```", text, re.S):
        for line in b.splitlines():
            line = line.split("#")[0].strip()
            if line.split(" ")[0].split("/")[-1] in prefixes:
                out.append(line)
    return out


def _run_line(line, cwd, subst=()):
    argv = shlex.split(line)
    argv[0] = str(BIN / Path(argv[0]).name)
    for a, b in subst:
        argv = [x.replace(a, b) for x in argv]
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "MPLBACKEND": "Agg"})


def test_experiments_page_commands_run(tmp_path):
    lines = block_lines(ROOT / "docs" / "experiments.md", {"springtrack"})
    assert len(lines) == 3
    for line in lines:
        if " simulate " in line:
            line += " --seconds 4"                    # the page's run, shortened
        r = _run_line(line, tmp_path)
        assert r.returncode == 0, f"{line}\n{r.stderr}"
    assert "mean_error_pct=" in r.stdout.splitlines()[-1]


@pytest.mark.slow
@pytest.mark.hil
def test_readme_device_commands_run_against_firmware(tmp_path, data_file):
    """The README's device block against a real firmware-sim process on the real replay it
    names: the hostctl lines in order (each exits 0), and the springtrack lines between
    them on what they wrote (the record drawn with the model downloaded from the device)."""
    data_dir = str(data_file("dvs.es").parent)
    text = (ROOT / "README.md").read_text()
    block = [b for b in re.findall(r"```[a-z]*\n(.*?)```", text, re.S) if _device_block(b)]
    assert len(block) == 1
    lines = [l.split("#")[0].strip() for l in block[0].splitlines()]
    lines = [l for l in lines if l]
    fw_line = lines[[l.startswith(".venv/bin/firmware-sim") for l in lines].index(True)]
    argv = [a.replace("../shared/data", data_dir) for a in shlex.split(fw_line)]
    argv[0] = str(BIN / "firmware-sim")
    (tmp_path / "scratch").mkdir()
    fw = subprocess.Popen(argv + ["--seconds", "30"], cwd=tmp_path, stdout=subprocess.PIPE,
                          stderr=subprocess.DEVNULL, text=True)
    try:
        first = fw.stdout.readline().strip()
        assert first.startswith("pty: "), first
        pty = first.split(" ", 1)[1]
        for line in lines:
            if line.split()[0].endswith(("hostctl", "springtrack")):
                r = _run_line(line, tmp_path, [("/dev/pts/N", pty), ("../shared/data", data_dir)])
                assert r.returncode == 0, f"{line}\n{r.stdout}\n{r.stderr}"
        rec = (tmp_path / "scratch" / "plane_dev.csv").read_text().splitlines()
        model = (tmp_path / "scratch" / "plane_dev.toml").read_text()
        ids = {r.split(",")[1] for r in rec[1:]}
        assert ids and all(f'id = "{i}"' in model for i in ids)      # one set of ids
        assert (tmp_path / "scratch" / "plane_dev.gif").stat().st_size > 0
    finally:
        fw.terminate()
        try:
            fw.wait(10)
        except subprocess.TimeoutExpired:
            fw.kill()


def python_blocks(path):
    """The fenced ```python blocks of a Markdown file."""
    return re.findall(r"```python\n(.*?)```", (ROOT / path).read_text(), re.S)


@pytest.mark.parametrize("path", ["README.md", "docs/learning.md"])
def test_python_snippets_run(path, data_file, monkeypatch):
    """Every Python block of the page runs as written, from the repository root with the
    real recordings at ../shared/data (as the page says they are)."""
    data = data_file("dvs.es").parent
    monkeypatch.chdir(ROOT)
    for block in python_blocks(path):
        code = block.replace("../shared/data", str(data))
        exec(compile(code, f"{path} python block", "exec"), {})
