"""The EVT 3.0 decoder without its AVX2 block path (io/evt3_block.h): a processor without
AVX2 (or ``SPRINGTRACK_SIMD=0``) decodes every word in the word loop, with the same events
and counters, and a build for a processor without AVX2 compiles the word loop alone."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import springtrack.io as sio
from springtrack.io import evt3
from test_io_decoders import evt3_mixed_words

# decodes each (path, width, height) of argv's JSON list with the decoder of this process
# and saves the events and counters next to the words
DECODE = """
import json, sys
import numpy as np
import springtrack.io as sio
from springtrack.io import evt3
for path, width, height in json.loads(sys.argv[1]):
    dec = sio.decoder("evt3", width=width, height=height)
    ev = dec.decode(open(path, "rb").read())
    np.save(path + ".events.npy", ev)
    json.dump({"path": evt3.block_path(), "words": dec.stats.words,
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
    """Each (path, width, height) decoded here and in a process with SPRINGTRACK_SIMD=0:
    asserts the same events and counters, and that the other process used the word loop."""
    env = {**os.environ, "SPRINGTRACK_SIMD": "0"}
    subprocess.run([sys.executable, "-c", DECODE, json.dumps(streams)], env=env, check=True)
    for path, width, height in streams:
        dec = sio.decoder("evt3", width=width, height=height)
        ev = dec.decode(open(path, "rb").read())
        np.testing.assert_array_equal(ev, np.load(path + ".events.npy"))
        other = json.load(open(path + ".stats.json"))
        assert other["path"] == "words"
        assert other["words"] == dec.stats.words
        assert other["anomalies"] == dec.stats.anomalies and other["info"] == dec.stats.info


@pytest.mark.skipif(not cpu_has_avx2(), reason="the processor has no AVX2")
def test_block_path_is_used_where_the_processor_has_avx2():
    assert evt3.block_path() == "avx2"


def test_word_loop_alone_on_hand_shaped_streams(tmp_path):
    streams = []
    for seed in (1, 2, 3, 4):
        path = tmp_path / f"mixed{seed}.evt3"
        path.write_bytes(evt3_mixed_words(seed))
        streams.append((str(path), 640, 480))
    same_without_simd(streams)


def test_word_loop_alone_on_the_recording(tmp_path, data_file):
    src = data_file("evt3_sample.raw")
    path = tmp_path / "evt3_sample.words"
    path.write_bytes(src.read_bytes()[sio.open(src).offset:])
    same_without_simd([(str(path), 1280, 720)])


# a translation unit using the block path's entry point, and the path its build must take
PROBE = """
#include "springtrack/io/evt3_block.h"
_Static_assert(EVT3_BLOCK_SIMD == EXPECT_SIMD, "the block path this target must build");
size_t probe(const uint8_t *p, size_t nw, Evt3Run *st, void *out, size_t *k, size_t *scalar)
{
    return evt3_decode_run(p, nw, st, 640, 480, out, k, 4096, scalar);
}
"""


@pytest.mark.parametrize("target, simd", [("aarch64-linux-gnu", 0), ("riscv64-linux-gnu", 0),
                                          ("x86_64-linux-gnu", 1)])
def test_header_builds_for_processors_without_avx2(tmp_path, target, simd):
    """With clang (the ziglang package) for other processors: no x86 intrinsic is left in
    the build (the word loop alone), and on x86-64 the AVX2 path builds with clang too,
    without -mavx2 (chosen at run time)."""
    pytest.importorskip("ziglang")
    from springtrack.mcu.build import cache_root, zig_cc
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    src = tmp_path / "probe.c"
    src.write_text(PROBE)
    res = subprocess.run([*zig_cc(), "-target", target, f"-DEXPECT_SIMD={simd}", "-I", root,
                          "-O2", "-Wall", "-Wextra", "-Werror", "-c", str(src), "-o",
                          str(tmp_path / "probe.o")], capture_output=True, text=True,
                         env={**os.environ, "ZIG_GLOBAL_CACHE_DIR": str(cache_root() / "zig")})
    assert res.returncode == 0, res.stderr
