"""The word decoders without their hand-written AVX2 blocks (EVT 2.0: io/evt2_block.h, EVT
3.0: io/evt3_block.h, chosen at run time: io/clones.h): a processor without AVX2 (or
``SPRINGTRACK_SIMD=0``) takes the portable paths, with the same events and counters, and a
build for a processor without AVX2 compiles the portable paths alone."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import springtrack.io as sio
from support.words import evt2_mixed_words, evt3_mixed_words
from support import REPO

# decodes each (format, path, width, height) of argv's JSON list with the decoders of this
# process and saves the events and counters next to the words
DECODE = """
import json, sys
import numpy as np
import springtrack.io as sio
for fmt, path, width, height in json.loads(sys.argv[1]):
    dec = sio.decoder(fmt, width=width, height=height)
    ev = dec.decode(open(path, "rb").read())
    np.save(path + ".events.npy", ev)
    json.dump({"path": sio.simd_path(), "words": dec.stats.words,
               "anomalies": dec.stats.anomalies, "info": dec.stats.info},
              open(path + ".stats.json", "w"))
"""


def cpu_has_avx2() -> bool:
    try:
        return any(line.startswith("flags") and "avx2" in line.split()
                   for line in open("/proc/cpuinfo"))
    except OSError:
        return False


def same_without_simd(streams):
    """Each (format, path, width, height) decoded here and in a process with
    SPRINGTRACK_SIMD=0: asserts the same events and counters, and that the other process
    took the portable paths."""
    env = {**os.environ, "SPRINGTRACK_SIMD": "0"}
    subprocess.run([sys.executable, "-c", DECODE, json.dumps(streams)], env=env, check=True)
    for fmt, path, width, height in streams:
        dec = sio.decoder(fmt, width=width, height=height)
        ev = dec.decode(open(path, "rb").read())
        np.testing.assert_array_equal(ev, np.load(path + ".events.npy"))
        other = json.load(open(path + ".stats.json"))
        assert other["path"] == "portable"
        assert other["words"] == dec.stats.words
        assert other["anomalies"] == dec.stats.anomalies and other["info"] == dec.stats.info


@pytest.mark.skipif(not cpu_has_avx2(), reason="the processor has no AVX2")
def test_avx2_blocks_run_where_the_processor_has_avx2():
    assert sio.simd_path() == "avx2"


def test_portable_paths_on_hand_shaped_streams(tmp_path):
    streams = []
    for fmt, words in (("evt2", evt2_mixed_words), ("evt3", evt3_mixed_words)):
        for seed in (1, 2, 3, 4):
            path = tmp_path / f"mixed{seed}.{fmt}"
            path.write_bytes(words(seed))
            streams.append((fmt, str(path), 640, 480))
    same_without_simd(streams)


def test_portable_paths_on_the_recordings(tmp_path, data_file):
    streams = []
    for fmt in ("evt2", "evt3"):
        src = data_file(f"{fmt}_sample.raw")
        reader = sio.open(src)
        path = tmp_path / f"{fmt}_sample.words"
        path.write_bytes(src.read_bytes()[reader.offset:])
        streams.append((fmt, str(path), reader.width, reader.height))
    same_without_simd(streams)


# a translation unit using the block paths' entry points, and whether its build must have
# the AVX2 blocks
PROBE = """
#include "springtrack/io/evt2_block.h"
#include "springtrack/io/evt3_block.h"
_Static_assert(IO_AVX2_BUILD == EXPECT_SIMD, "the block paths this target must build");
size_t probe(const uint8_t *p, size_t nw, Evt3Run *st, void *out, size_t *k, size_t *scalar)
{
    return evt3_decode_run(p, nw, st, 640, 480, out, k, 4096, scalar)
           + (size_t)evt2_decode_block(p, 0, 640, 480, out);
}
"""


@pytest.mark.parametrize("target, simd", [("aarch64-linux-gnu", 0), ("riscv64-linux-gnu", 0),
                                          ("x86_64-linux-gnu", 1)])
def test_header_builds_for_processors_without_avx2(tmp_path, target, simd):
    """With clang (the ziglang package) for other processors: no x86 intrinsic is left in
    the build (the portable paths alone), and on x86-64 the AVX2 blocks build with clang
    too, without -mavx2 (chosen at run time)."""
    pytest.importorskip("ziglang")
    from springtrack.mcu.build import cache_root, zig_cc
    root = str(REPO)
    src = tmp_path / "probe.c"
    src.write_text(PROBE)
    res = subprocess.run([*zig_cc(), "-target", target, f"-DEXPECT_SIMD={simd}", "-I", root,
                          "-O2", "-Wall", "-Wextra", "-Werror", "-c", str(src), "-o",
                          str(tmp_path / "probe.o")], capture_output=True, text=True,
                         env={**os.environ, "ZIG_GLOBAL_CACHE_DIR": str(cache_root() / "zig")})
    assert res.returncode == 0, res.stderr
