"""Minimal protobuf wire-format and TFRecord readers (standard library only).

Only what the Waymo reader needs: split a message into ``{field number: [raw values]}`` and
decode scalars / repeated doubles (packed or not). No schema compilation, no TensorFlow.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Iterator

from ..errors import FormatError

__all__ = ["iter_tfrecords", "parse_message", "as_int", "as_double", "as_doubles", "as_string", "as_messages"]

_VARINT, _I64, _LEN, _I32 = 0, 1, 2, 5


def iter_tfrecords(path) -> Iterator[bytes]:
    """Payloads of a TFRecord file: ``uint64 length | uint32 crc | data | uint32 crc`` per record
    (CRCs are not verified; lengths are)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"TFRecord file not found: {path}")
    data = path.read_bytes()
    pos, n = 0, 0
    while pos < len(data):
        if pos + 12 > len(data):
            raise FormatError(path, f"record {n}: truncated header at byte {pos} of {len(data)}")
        (length,) = struct.unpack_from("<Q", data, pos)
        start = pos + 12
        end = start + length
        if end + 4 > len(data):
            raise FormatError(path, f"record {n}: length {length} runs past the end of the file "
                                    f"({len(data)} bytes); truncated or not a TFRecord")
        yield data[start:end]
        pos, n = end + 4, n + 1


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    result, shift = 0, 0
    while True:
        if pos >= len(buf):
            raise ValueError("truncated varint")
        b = buf[pos]
        result |= (b & 0x7F) << shift
        pos += 1
        if not b & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise ValueError("varint longer than 10 bytes")


def parse_message(buf: bytes) -> dict[int, list[tuple[int, object]]]:
    """``{field number: [(wire type, value), ...]}``; value is an int (varint), 8/4 raw bytes
    (fixed64/fixed32) or the bytes of a length-delimited field. Raises ValueError when malformed."""
    out: dict[int, list[tuple[int, object]]] = {}
    pos = 0
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        field, wt = key >> 3, key & 7
        if wt == _VARINT:
            val, pos = _varint(buf, pos)
        elif wt == _I64:
            val, pos = buf[pos:pos + 8], pos + 8
        elif wt == _LEN:
            n, pos = _varint(buf, pos)
            val, pos = buf[pos:pos + n], pos + n
        elif wt == _I32:
            val, pos = buf[pos:pos + 4], pos + 4
        else:
            raise ValueError(f"unsupported wire type {wt} for field {field}")
        if pos > len(buf):
            raise ValueError(f"field {field} runs past the end of the message")
        out.setdefault(field, []).append((wt, val))
    return out


def as_int(msg: dict, field: int, default: int | None = None) -> int | None:
    vals = msg.get(field)
    if not vals:
        return default
    wt, v = vals[-1]
    if wt != _VARINT:
        raise ValueError(f"field {field}: expected a varint, got wire type {wt}")
    return int(v)


def as_double(msg: dict, field: int, default: float | None = None) -> float | None:
    vals = as_doubles(msg, field)
    return vals[-1] if vals else default


def as_doubles(msg: dict, field: int) -> list[float]:
    """Repeated double, packed (one length-delimited blob) or unpacked (one fixed64 each)."""
    out: list[float] = []
    for wt, v in msg.get(field, []):
        if wt == _I64:
            out.append(struct.unpack("<d", v)[0])
        elif wt == _LEN:
            if len(v) % 8:
                raise ValueError(f"field {field}: packed doubles of {len(v)} bytes")
            out.extend(struct.unpack(f"<{len(v) // 8}d", v))
        else:
            raise ValueError(f"field {field}: expected doubles, got wire type {wt}")
    return out


def as_string(msg: dict, field: int, default: str = "") -> str:
    vals = msg.get(field)
    if not vals:
        return default
    return bytes(vals[-1][1]).decode("utf-8", errors="replace")


def as_messages(msg: dict, field: int) -> list[dict]:
    return [parse_message(v) for wt, v in msg.get(field, []) if wt == _LEN]
