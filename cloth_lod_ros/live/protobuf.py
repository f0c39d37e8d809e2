"""Protocol Buffers wire format for the bulk fields of a mesh, with numpy.

The ``foxglove`` SDK builds a message from one Python object per point: 0.14 s
for a 10 000-triangle mesh (measured), too slow for every frame.  A protobuf
message is a sequence of ``(key, value)`` fields in any order, and a repeated
field may be split over several runs that a parser concatenates, so the SDK
encodes the small parts of a primitive (pose, colour) and this module appends
the large repeated ones: ``Point3`` points as one fixed-size record each (an
``(n, 29)`` byte array written by a structured dtype) and indices as a packed
``fixed32`` run.

Reference: Protocol Buffers encoding, https://protobuf.dev/programming-guides/encoding/
(varints, keys ``field << 3 | wire type``, wire types 1 = I64, 2 = LEN, 5 = I32;
"packed repeated fields"; "last one wins" / concatenation of repeated fields).
"""

from __future__ import annotations

import numpy as np

__all__ = ["varint", "field_key", "length_delimited", "repeated_point3", "packed_fixed32"]

I64, LEN = 1, 2                         # wire types

# foxglove.Point3 {double x = 1; double y = 2; double z = 3;} as one element of
# a repeated field: key, length 27, then three (key, little-endian double) pairs.
_POINT3 = np.dtype([("key", "u1"), ("length", "u1"),
                    ("kx", "u1"), ("x", "<f8"), ("ky", "u1"), ("y", "<f8"),
                    ("kz", "u1"), ("z", "<f8")])            # packed: 29 bytes
assert _POINT3.itemsize == 29


def varint(value: int) -> bytes:
    """Base-128 varint of a non-negative integer (least significant group first)."""
    value = int(value)
    if value < 0:
        raise ValueError("varint of a negative number")
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def field_key(field: int, wire_type: int) -> bytes:
    """The key of field number ``field`` with ``wire_type``."""
    return varint(field << 3 | wire_type)


def length_delimited(field: int, payload: bytes) -> bytes:
    """Field ``field`` holding ``payload`` (a sub-message, string or packed run)."""
    return field_key(field, LEN) + varint(len(payload)) + payload


def repeated_point3(field: int, points: np.ndarray) -> bytes:
    """Field ``field`` of type ``repeated foxglove.Point3`` holding ``points`` ``(n, 3)`` m."""
    if field >= 16:                     # the key must fit one byte for the fixed record
        raise ValueError("field numbers up to 15 only")
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    rec = np.empty(len(pts), dtype=_POINT3)
    rec["key"] = field << 3 | LEN
    rec["length"] = _POINT3.itemsize - 2
    rec["kx"], rec["ky"], rec["kz"] = 1 << 3 | I64, 2 << 3 | I64, 3 << 3 | I64
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    return rec.tobytes()


def packed_fixed32(field: int, values: np.ndarray) -> bytes:
    """Field ``field`` of type ``repeated fixed32`` holding ``values`` (packed)."""
    data = np.ascontiguousarray(values, dtype="<u4").tobytes()
    return length_delimited(field, data) if data else b""
