"""Words images: models and parameters for a firmware that cannot parse TOML, through the
host link's model upload (docs/protocol.md, "Words images"; springtrack/wire.py is the rest
of the protocol).  Both ends use this one definition: hostctl encodes, the microcontroller
image (springtrack/mcu/firmware/proto.c) decodes with the constants that
springtrack/mcu/wire_header.py generates from it.
"""
from __future__ import annotations

import struct
from enum import IntEnum

import numpy as np

from ..wire import WireError, _Cursor, _text, decode_kv, encode_kv

# A firmware whose INFO says ``model_format: "words"`` (the microcontroller image,
# springtrack/mcu/firmware/) takes, through MODEL_BEGIN / CHUNK / COMMIT, this image instead
# of TOML text: the fixed-point kernel's word streams (springtrack.fixed.q), converted and
# checked against springtrack.limits by the host, and checked again by the firmware:
#   magic "STWI", u8 image version, u8 kind (ImageKind), u16 kv length, kv list of the
#   parameters (what PARAM_GET answers)
#   kind MODEL: str16 model name, u8 tracker count n, n x str8 tracker id,
#               u32 model word count, the words (fixed_q.model_words, int32)
#   u32 parameter word count, the words (fixed_q.params_words, int32)
IMAGE_HDR = struct.Struct("<4sBBH")
IMAGE_MAGIC = b"STWI"
IMAGE_VERSION = 1
MODEL_FORMAT_WORDS = "words"      # INFO's model_format of a firmware that takes images


class ImageKind(IntEnum):
    MODEL = 1             # a model, with its parameters
    PARAMS = 2            # parameters for the running model


def encode_image(kind: ImageKind, params: dict, params_words, name: str = "", ids=(),
                 model_words=None) -> bytes:
    """A words image (layout above); ``params`` is the parameters as a dict of plain
    values, ``*_words`` int32 arrays."""
    kv = encode_kv(params)
    out = IMAGE_HDR.pack(IMAGE_MAGIC, IMAGE_VERSION, int(kind), len(kv)) + kv
    if kind == ImageKind.MODEL:
        ids = list(ids)
        if len(ids) > 255:
            raise WireError(f"a words image carries at most 255 tracker ids, got {len(ids)}")
        mw = np.asarray(model_words, "<i4")
        out += (_text(name, "H") + bytes([len(ids)]) + b"".join(_text(i) for i in ids)
                + struct.pack("<I", len(mw)) + mw.tobytes())
    pw = np.asarray(params_words, "<i4")
    return out + struct.pack("<I", len(pw)) + pw.tobytes()


def decode_image(data: bytes) -> dict:
    """The fields of a words image: kind, params, name, ids, model_words, params_words."""
    c = _Cursor(bytes(data), "words image")
    magic, version, kind, nkv = c.unpack(IMAGE_HDR.format[1:], "header")
    if magic != IMAGE_MAGIC or version != IMAGE_VERSION or kind not in (1, 2):
        raise WireError(f"words image: header {magic!r} v{version} kind {kind} is not "
                        f"{IMAGE_MAGIC!r} v{IMAGE_VERSION}")
    out = dict(kind=ImageKind(kind), params=decode_kv(c.take(nkv, "params"), "words image"))
    if kind == ImageKind.MODEL:
        out["name"] = c.text("name", "H")
        out["ids"] = [c.text(f"id {i}") for i in range(c.u8("ids"))]
        (n,) = c.unpack("I", "model words")
        out["model_words"] = np.frombuffer(c.take(4 * n, "model words"), "<i4")
    (n,) = c.unpack("I", "params words")
    out["params_words"] = np.frombuffer(c.take(4 * n, "params words"), "<i4")
    c.done()
    return out


def words_image(text: bytes) -> tuple[bytes, int]:
    """A model's words image (:func:`encode_image`) for a firmware whose INFO says
    model_format "words" (the microcontroller image, docs/mcu.md): the model parsed and
    checked as firmware_sim checks an uploaded TOML text, its parameters (defaults, then
    its [params]) and both converted by springtrack.fixed.q; and its connection count."""
    from .. import model as _model, params as _params
    from ..fixed import q as fixed_q
    m = _model.loads(text, "uploaded model")
    p = _params.resolve(m)
    nc = len(m.connections)
    return encode_image(ImageKind.MODEL, p.as_dict(), fixed_q.params_words(p, nc), m.name,
                        [t.id for t in m.trackers],
                        fixed_q.model_words(m.arrays(), m.width, m.height)), nc


def params_image(values: dict, nc: int) -> bytes:
    """A parameters image of ``values`` (all of them, as PARAM_GET gives them, changed) for
    the running model's ``nc`` connections."""
    from .. import params as _params
    from ..fixed import q as fixed_q
    p = _params.from_mapping(values)
    return encode_image(ImageKind.PARAMS, p.as_dict(), fixed_q.params_words(p, nc))
