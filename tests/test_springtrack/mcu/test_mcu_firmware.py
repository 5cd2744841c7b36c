"""The firmware image (springtrack/mcu/firmware/, docs/mcu.md "The firmware image"):
``springtrack mcu build --board`` for the QEMU boards, booted by ``springtrack mcu run``
in qemu-system-arm and steered by hostctl over a pty, as separate processes:

* the image has a vector table, needs no runtime helper and has no FPU instruction;
* every frame the C link sends is byte for byte what springtrack/wire.py encodes (COBS,
  CRC-32, the generated codes);
* hostctl uploads a model (as a words image), starts, records: the recording equals the one
  of ``firmware-sim run --backend fixed`` on the same events, on an STM32F405 and on the
  MPS2 boards;
* hostile frames and bad models are refused as firmware_sim refuses them, and change
  nothing.

QEMU comes from Debian (qemu-system-arm), installed by ``make test``; without it these tests
skip, except in CI (CI=true), where they fail."""
import os
import struct
import subprocess
import time
import zlib

import numpy as np
import pytest

from support.mcu_image import require_qemu  # noqa: E402

require_qemu()

import serial  # noqa: E402

from hostctl import Device  # noqa: E402
from hostctl.device import Nacked  # noqa: E402
from springtrack import wire  # noqa: E402
from springtrack.io.cobs import CobsError  # noqa: E402
from springtrack.mcu import words as wire_image  # noqa: E402
from springtrack.mcu.words import words_image  # noqa: E402
from springtrack.fixed import q as fixed_q  # noqa: E402
from springtrack.mcu.boards import BOARDS  # noqa: E402
from springtrack.mcu.qemu import Qemu  # noqa: E402
from springtrack.model import face26  # noqa: E402
from springtrack.wire import MsgType, Nack  # noqa: E402

from support.elf import RUNTIME, symbols, text_mnemonics  # noqa: E402
from support.fwproc import Firmware, hostctl_cmd  # noqa: E402
from support.mcu_image import (H, W, image, run_to_end, same_snapshots,  # noqa: E402
                                springtrack_cmd, write_scene)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """0.2 s of the face scene as RAW EVT 2.0 and 2.1 recordings, and face26 on its sensor
    as a TOML file (support.mcu_image.write_scene)."""
    d = tmp_path_factory.mktemp("scene")
    write_scene(d)
    return d


# ---- the image ------------------------------------------------------------------------
@pytest.mark.parametrize("board", list(BOARDS))
def test_image_has_vectors_no_runtime_and_no_fpu(board):
    res = image(board)
    from elftools.elf.elffile import ELFFile
    with open(res.elf, "rb") as f:
        e = ELFFile(f)
        text = e.get_section_by_name(".text")
        sp, pc = struct.unpack_from("<II", text.data())
        reset = next(s["st_value"] for s in e.get_section_by_name(".symtab").iter_symbols()
                     if s.name == "reset_handler")
    b = BOARDS[board]
    assert text["sh_addr"] == b.flash[0], "the vector table opens the flash"
    assert b.ram[0] < sp <= b.ram[0] + b.ram[1], "initial stack pointer in RAM"
    assert pc == reset | 1, "reset vector: the reset handler, Thumb"
    syms = symbols(res.elf)
    assert not [n for n, _, shndx in syms if shndx == "SHN_UNDEF"]
    assert not [n for n, _, _ in syms if RUNTIME.match(n)]
    assert not {m for m in text_mnemonics(res) if m.startswith("v")}, "FPU instructions"
    assert res.ram_bytes <= b.ram[1] and res.flash_bytes <= b.flash[1]


def test_cli_build_writes_firmware_elf(tmp_path):
    r = subprocess.run(springtrack_cmd("mcu", "build", "--board", "mps2-an500", "--out",
                                       str(tmp_path), "--model", "grid3x3"),
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "firmware.elf").exists()
    assert "flash_bytes=" in r.stdout.splitlines()[-1]
    assert "#define MSG_TELEMETRY 64" in (tmp_path / "wire_codes.h").read_text()


# ---- the link, frame by frame ----------------------------------------------------------
def raw_frames(port, seconds=1.0):
    """The delimited chunks the firmware sent within ``seconds``."""
    data = b""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        data += port.read(4096)
    return [c for c in data.split(b"\x00") if c]


def send(port, mtype, seq, payload=b"", **kw):
    port.write(b"\x00" + wire.encode_frame(mtype, seq, payload, **kw))


def _decodes(chunk):
    """The chunk's frame type, None if it is no whole frame (e.g. cut by the end of a read
    window: its COBS blocks run past its end)."""
    try:
        return wire.decode_frame(chunk).type
    except (wire.WireError, CobsError):
        return None


def hello(port, seq=1, seconds=60.0):
    """HELLO, sent again every half second until INFO comes (bytes sent while the image
    boots are lost); the chunks received, INFO among them."""
    end, chunks = time.monotonic() + seconds, []
    while time.monotonic() < end:
        send(port, MsgType.HELLO, seq, wire.encode_hello("test"))
        chunks += raw_frames(port, 0.5)
        if any(_decodes(c) == MsgType.INFO for c in chunks):
            return chunks
    raise AssertionError("no INFO")


def test_every_frame_the_c_link_sends_is_what_wire_encodes(scene):
    """INFO (a JSON of more than 254 bytes without a zero: COBS's 255 code), ACK, NACK,
    PARAM_VALUE, STATS parts, APPLIED, TELEMETRY and NOTICE: decoded by wire.py and encoded
    again, each is the same bytes."""
    with Qemu(image("mps2-an386").elf, "mps2-an386", scene / "face.raw") as q:
        port = serial.serial_for_url(q.link, timeout=0.05)
        port.write(b"\x00")
        chunks = hello(port)
        send(port, MsgType.PARAM_GET, 2, wire.encode_param_get([]))
        send(port, MsgType.STATS, 3)
        send(port, 0x77, 4)
        img, _ = words_image((scene / "face.toml").read_bytes())
        send(port, MsgType.MODEL_BEGIN, 5, wire.encode_model_begin(img))
        for k, off in enumerate(range(0, len(img), wire.MODEL_CHUNK_SIZE)):
            send(port, MsgType.MODEL_CHUNK, 6 + k, wire.encode_model_chunk(
                off, img[off:off + wire.MODEL_CHUNK_SIZE]))
            chunks += raw_frames(port, 0.05)
        send(port, MsgType.MODEL_COMMIT, 100, wire.encode_model_begin(img))
        send(port, MsgType.START, 101)
        chunks += raw_frames(port, 3.0)
        port.close()
    # the host hunts: what reached the pty before QEMU saw it opened may be cut (QEMU's pty
    # drops output while it has no reader), so frames count from the first whole INFO, and
    # a frame cut on the way is the link's to count (tests/test_hostctl_hil.py), not this
    # test's: every frame that arrives whole must be wire's bytes
    first = next(i for i, c in enumerate(chunks) if _decodes(c) == MsgType.INFO)
    chunks = [c for c in chunks[first:] if _decodes(c) is not None]
    types = {}
    for c in chunks:
        f = wire.decode_frame(c)
        assert c + b"\x00" == wire.encode_frame(f.type, f.seq, f.payload), MsgType(f.type).name
        types[f.type] = f
    assert {MsgType.INFO, MsgType.ACK, MsgType.NACK, MsgType.STATS, MsgType.APPLIED,
            MsgType.TELEMETRY, MsgType.NOTICE} <= set(types)
    assert len(wire.cobs_decode(next(c for c in chunks if wire.decode_frame(c).type
                                     == MsgType.INFO))) > 254
    assert wire.decode_nack(types[MsgType.NACK].payload).code == Nack.UNKNOWN_TYPE


# ---- the whole chain, against firmware-sim --------------------------------------------
def record_api(link, model):
    with Device(link, timeout=0.5, retries=20) as dev:
        info = dev.info
        dev.load_model(model)
        info = dev.hello()                   # INFO names the uploaded model's trackers
        snaps = run_to_end(dev)
        return snaps, info, dev.stats(), dev.link_counters()["lost"]


def firmware_sim_fixed(scene, recording="face.raw"):
    fw = Firmware("--source", f"replay:{scene / recording}", "--backend", "fixed",
                  "--max-speed", "--pty", "--wait-start", "--model", str(scene / "face.toml"))
    try:
        return record_api(fw.path, scene / "face.toml")
    finally:
        fw.close()


_references = {}


@pytest.mark.parametrize("board,recording", [("mps2-an386", "face21.raw"),
                                             ("mps2-an500", "face.raw")])
def test_mps2_telemetry_equals_firmware_sim_fixed(scene, board, recording):
    """hostctl's upload, start and telemetry through the image on an MPS2 board, from an
    EVT 2.1 and an EVT 2.0 recording: every snapshot (time, mean energy, every tracker
    field) equals firmware-sim --backend fixed's on the same recording."""
    if recording not in _references:
        _references[recording] = firmware_sim_fixed(scene, recording)
    ref, ref_info, ref_st, _ = _references[recording]
    with Qemu(image(board).elf, board, scene / recording) as q:
        snaps, info, st, lost = record_api(q.link, scene / "face.toml")
    same_snapshots(snaps, ref)
    assert lost == 0 and st["state"] == "ended"
    assert info["trackers"] == ref_info["trackers"]
    assert st["events_tracked"] == ref_st["events_tracked"] == st["events_decoded"]
    assert st["decode.outside_sensor"] == st["decode.gap_skipped"] == 0


def test_cli_chain_on_netduinoplus2_records_what_firmware_sim_fixed_does(scene, tmp_path):
    """The issue's check, as a user runs it: springtrack mcu build --board netduinoplus2,
    springtrack mcu run ... --pty, hostctl load-model, then record --start (START sent by
    the recording process, so that it holds the stream from its first snapshot): the CSV
    equals hostctl's recording of firmware-sim run --backend fixed on the same events, byte
    for byte."""
    out = tmp_path / "nd"
    r = subprocess.run(springtrack_cmd("mcu", "build", "--board", "netduinoplus2", "--out",
                                       str(out)), capture_output=True, text=True, cwd=ROOT,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    csvs = {}
    for name in ("mcu", "fixed"):
        if name == "mcu":
            proc = subprocess.Popen(springtrack_cmd("mcu", "run", str(out / "firmware.elf"),
                                                    "--board", "netduinoplus2", "--events",
                                                    str(scene / "face.raw"), "--pty"),
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    cwd=ROOT)
            line = proc.stdout.readline()
            assert line.startswith("pty: "), (line, proc.stderr.read() if proc.poll() else "")
            link, close = line.split()[1], proc
        else:
            fw = Firmware("--source", f"replay:{scene / 'face.raw'}", "--backend", "fixed",
                          "--max-speed", "--pty", "--wait-start")
            link, close = fw.path, fw
        try:
            for verb in (["load-model", str(scene / "face.toml")],
                         ["record", str(tmp_path / f"{name}.csv"), "--start", "--until-end",
                          "--seconds", "120"]):
                r = subprocess.run(hostctl_cmd("--port", link, "--retries", "20", *verb),
                                   capture_output=True, text=True, cwd=ROOT, timeout=300)
                assert r.returncode == 0, (name, verb, r.stdout, r.stderr)
            r = subprocess.run(hostctl_cmd("--port", link, "shutdown"), capture_output=True,
                               text=True, cwd=ROOT, timeout=60)
            if name == "mcu":                     # SHUTDOWN ends the image, and QEMU (its pty
                assert proc.wait(30) == 0, r.stderr   # may close before hostctl reads the ACK)
            else:
                assert r.returncode == 0, r.stderr
        finally:
            if name == "mcu":
                if proc.poll() is None:
                    proc.terminate()
                    proc.wait(10)
                proc.stdout.close()
                proc.stderr.close()
            else:
                close.close()
        csvs[name] = (tmp_path / f"{name}.csv").read_bytes()
    assert csvs["mcu"].count(b"\n") > 150 * 26
    assert csvs["mcu"] == csvs["fixed"]


# ---- hostile input ---------------------------------------------------------------------
def bad_words_image(scene, **change):
    """face26's words image with a word changed after the host's checks: what a broken or
    hostile host could send."""
    img, _ = words_image((scene / "face.toml").read_bytes())
    d = wire_image.decode_image(img)
    mw = d["model_words"].copy()
    n = int(mw[0])
    conn0 = 8 + 16 * n
    if "stiffness" in change:
        mw[conn0 + 3] = int(change["stiffness"] * 2 ** 30)
    if "width" in change:
        mw[2] = change["width"]
    if "tracker" in change:
        mw[conn0] = change["tracker"]
    if "mass" in change:                         # 1/mass, Q.24
        mw[8 + 11] = int(2 ** 24 / change["mass"])
    return wire_image.encode_image(wire_image.ImageKind.MODEL, d["params"], d["params_words"],
                             change.get("name", "face26"), d["ids"], mw)


def upload_raw(dev, img):
    return dev._upload(img)


def test_hostile_frames_and_bad_models_are_refused_and_change_nothing(scene):
    with Qemu(image("mps2-an386").elf, "mps2-an386", scene / "face.raw") as q:
        # frames before a session, garbage, and a corrupt frame
        port = serial.serial_for_url(q.link, timeout=0.05)
        end = time.monotonic() + 30                  # up: STATS answered (no session needed)
        while not any(_decodes(c) == MsgType.STATS for c in raw_frames(port, 0.5)):
            assert time.monotonic() < end, "the image does not answer"
            send(port, MsgType.STATS, 8)
        port.write(b"\x00" + bytes(range(1, 200)) + b"\x00")           # bad COBS / CRC
        good = wire.encode_frame(MsgType.START, 9)
        port.write(b"\x00" + good[:3] + bytes([good[3] ^ 0x40]) + good[4:])   # a flipped bit
        port.write(b"\x07" * 2000 + b"\x00")                           # no delimiter: oversize
        send(port, MsgType.START, 10)                                  # before HELLO
        send(port, MsgType.STATS, 11, version=2)                       # another version
        got = [wire.decode_frame(c) for c in raw_frames(port, 3.0)]
        nacks = [wire.decode_nack(f.payload) for f in got if f.type == MsgType.NACK]
        assert [n.code for n in nacks] == [Nack.FORBIDDEN, Nack.VERSION_MISMATCH]
        assert "firmware=v1 host=v2" in nacks[1].reason
        port.close()
        with Device(q.link, timeout=0.5, retries=20) as dev:
            st = dev.stats()
            assert st["link.crc_errors"] + st["link.cobs_errors"] >= 2
            assert st["link.oversize"] == 1 and st["link.forbidden"] == 1
            gen = dev.load_model(scene / "face.toml")
            cases = {Nack.INVALID_MODEL: [dict(stiffness=0.9), dict(tracker=99),
                                          dict(mass=1e6)],
                     Nack.SENSOR_MISMATCH: [dict(width=320)],
                     Nack.TOO_LONG: [dict(name="n" * 600)]}
            for code, changes in cases.items():
                for ch in changes:
                    with pytest.raises(Nacked) as e:
                        upload_raw(dev, bad_words_image(scene, **ch))
                    assert e.value.code == code, (ch, e.value)
            for payload in (b"", b"\x01\x02", struct.pack("<II", 10 ** 9, 0)):
                with pytest.raises(Nacked) as e:
                    dev._command(MsgType.MODEL_BEGIN, payload)
                assert e.value.code in (Nack.MALFORMED, Nack.OUT_OF_RANGE)
            with pytest.raises(Nacked) as e:
                dev._command(MsgType.MODEL_COMMIT, struct.pack("<II", 1, 2))
            assert e.value.code == Nack.BAD_STATE
            dev._command(MsgType.MODEL_BEGIN, struct.pack("<II", 16, zlib.crc32(b"x" * 16)))
            with pytest.raises(Nacked) as e:
                dev._command(MsgType.MODEL_CHUNK, struct.pack("<I", 10) + b"y" * 10)
            assert e.value.code == Nack.OUT_OF_RANGE
            with pytest.raises(Nacked) as e:                      # 6 bytes never sent
                dev._command(MsgType.MODEL_COMMIT, struct.pack("<II", 16, zlib.crc32(b"x" * 16)))
            assert e.value.code == Nack.INVALID_MODEL
            with pytest.raises(Nacked) as e:
                dev.set(alpha_position=5.0)                       # PARAM_SET by name
            assert e.value.code == Nack.OUT_OF_RANGE
            st = dev.stats()
            assert st["generation"] == gen and st["updates_rejected"] == 6
            assert dev.get("alpha_position") == {"alpha_position": 0.2}
            dev.start()                                           # still tracks
            assert len(list(dev.telemetry(seconds=2.0))) > 10


def test_bad_models_are_refused_with_firmware_sims_codes(scene):
    """The same bad models through hostctl: the TOML firmware-sim gets and the words image
    the MCU image would get are refused with the same code (the host checks a words
    upload first, with firmware_sim's own model parser)."""
    m = face26(cx=W / 2, cy=H / 2, width=W, height=H)
    stiff = m.to_toml().replace("stiffness = 0.02", "stiffness = 0.5")
    assert stiff != m.to_toml()
    wide = face26(cx=W / 2, cy=H / 2, width=320, height=240).to_toml()
    fw = Firmware("--source", f"replay:{scene / 'face.raw'}", "--backend", "fixed",
                  "--max-speed", "--pty", "--wait-start")
    codes = {}
    try:
        with Device(fw.path, timeout=0.5, retries=20) as dev:
            for name, text in (("stiff", stiff), ("wide", wide)):
                with pytest.raises(Nacked) as e:
                    dev.load_model(text)
                codes[name] = e.value.code
    finally:
        fw.close()
    with Qemu(image("mps2-an386").elf, "mps2-an386", scene / "face.raw") as q:
        with Device(q.link, timeout=0.5, retries=20) as dev:
            with pytest.raises(Nacked) as e:
                dev.load_model(stiff)
            assert e.value.code == codes["stiff"] == Nack.INVALID_MODEL
            with pytest.raises(Nacked) as e:
                dev.load_model(wide)                              # refused by the firmware
            assert e.value.code == codes["wide"] == Nack.SENSOR_MISMATCH


def test_cli_profile_counts_the_image(scene, tmp_path):
    """springtrack mcu profile --board: the whole image's instructions per event in QEMU
    (-icount), more than the decoder's share, and its static RAM."""
    r = subprocess.run(springtrack_cmd("mcu", "profile", str(scene / "face.raw"), "--model",
                                       str(scene / "face.toml"), "--board", "mps2-an386",
                                       "--events", "3000"),
                       capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert r.returncode == 0, r.stderr
    last = dict(kv.split("=") for kv in r.stdout.splitlines()[-1].split())
    assert 300 < float(last["instructions_per_event"]) < 20_000
    assert 20_000 < int(last["ram_bytes"]) < 128 * 1024
    assert "of which decoding the words" in r.stdout


def test_a_keyed_image_answers_only_signed_frames(scene, tmp_path):
    """An image built with --key-file: hostctl with the key uploads, starts and receives
    telemetry over signed frames; without it the device says a key is needed; with a
    wrong key the signed ping goes unanswered (AuthFailed), and unsigned, forged and
    replayed frames are dropped and counted."""
    from hostctl.device import AuthFailed, HostctlError
    key = b"k" * 32
    (tmp_path / "key").write_bytes(key)
    r = subprocess.run(springtrack_cmd("mcu", "build", "--board", "mps2-an386", "--out",
                                       str(tmp_path / "img"), "--model", str(scene / "face.toml"),
                                       "--key-file", str(tmp_path / "key")),
                       capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0, r.stderr
    with Qemu(tmp_path / "img" / "firmware.elf", "mps2-an386", scene / "face.raw") as q:
        with pytest.raises(HostctlError, match="requires a key"):
            Device(q.link, timeout=0.5, retries=20)
        with pytest.raises(AuthFailed):
            Device(q.link, timeout=1.0, retries=3, key=b"w" * 32)   # room for a loaded host
        port = serial.serial_for_url(q.link, timeout=0.05)
        info = wire.decode_info(next(wire.decode_frame(c) for c in hello(port)
                                     if _decodes(c) == MsgType.INFO).payload)
        assert info["auth_required"]
        send(port, MsgType.STATS, 2)                                   # unsigned
        signer = wire.Signer(key, info["nonce"])
        frame = wire.encode_frame(MsgType.STATS, 3, signer=signer)
        port.write(b"\x00" + frame)                                    # authentic
        end = time.monotonic() + 30
        while not any(_decodes(c) == MsgType.STATS for c in raw_frames(port, 0.5)):
            assert time.monotonic() < end, "no answer to an authentic frame"
        port.write(b"\x00" + frame)                                    # replayed: no
        assert all(_decodes(c) == MsgType.HEARTBEAT for c in raw_frames(port, 0.5))  # answer
        port.close()
        with Device(q.link, timeout=0.5, retries=20, key=key) as dev:
            dev.load_model(scene / "face.toml")
            dev.start()
            assert len(list(dev.telemetry(seconds=2.0))) > 10
            st = dev.stats()
    assert st["link.auth_unsigned"] >= 1 and st["link.auth_bad_tag"] >= 1
    assert st["link.auth_replay"] >= 1


def test_words_image_round_trips():
    m = face26()
    img, nc = words_image(m.to_toml().encode())
    d = wire_image.decode_image(img)
    assert nc == len(m.connections) and d["name"] == m.name
    assert d["ids"] == [t.id for t in m.trackers]
    assert np.array_equal(d["model_words"], fixed_q.model_words(m.arrays(), m.width, m.height))
    with pytest.raises(wire.WireError):
        wire_image.decode_image(img[:-1])
