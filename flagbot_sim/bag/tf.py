"""CDR of ``tf2_msgs/msg/TFMessage`` written from its definition: recordings carry /tf without the tf2_msgs wheel.

The type (tf2_msgs, as in ROS 2 Jazzy)::

    TFMessage:          geometry_msgs/TransformStamped[] transforms
    TransformStamped:   std_msgs/Header header (builtin_interfaces/Time stamp: int32 sec, uint32 nanosec;
                        string frame_id), string child_frame_id, geometry_msgs/Transform transform
    Transform:          Vector3 translation (float64 x, y, z), Quaternion rotation (float64 x, y, z, w)

CDR (XCDR1, little endian, as rmw_fastrtps writes it): a 4-byte encapsulation header ``00 01 00 00``, then the
fields in order, each aligned to its own size counted from the end of that header; a sequence or a string is a
uint32 count first, a string's count includes its terminating NUL. No ROS import.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Iterable

#: the type's name as schemas and the graph give it
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: its own .msg text (tf2_msgs/msg/TFMessage.msg); the nested types come from geometry_msgs and std_msgs
TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"

_ENCAPSULATION = b"\x00\x01\x00\x00"       # CDR_LE, no options


@dataclass(frozen=True)
class Transform:
    """One ``geometry_msgs/TransformStamped``: ``child`` relative to ``parent`` at ``stamp_ns`` (the pose of the
    child frame in the parent frame: translation in m, rotation a unit quaternion x, y, z, w)."""
    stamp_ns: int
    parent: str
    child: str
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)


class _Out:
    def __init__(self):
        self.buf = bytearray(_ENCAPSULATION)

    def align(self, n: int) -> None:
        self.buf += b"\x00" * (-(len(self.buf) - 4) % n)

    def pack(self, fmt: str, *values, size: int) -> None:
        self.align(size)
        self.buf += struct.pack("<" + fmt, *values)

    def string(self, s: str) -> None:
        raw = s.encode("utf-8")
        if b"\x00" in raw:
            raise ValueError(f"a frame name cannot hold a NUL character: {s!r}")
        self.pack("I", len(raw) + 1, size=4)
        self.buf += raw + b"\x00"


def encode_tf_message(transforms: Iterable[Transform]) -> bytes:
    """The serialized ``tf2_msgs/msg/TFMessage`` holding ``transforms`` (what rclpy's serialize_message gives)."""
    items = list(transforms)
    out = _Out()
    out.pack("I", len(items), size=4)
    for t in items:
        sec, nsec = divmod(int(t.stamp_ns), 1_000_000_000)
        out.pack("iI", sec, nsec, size=4)
        out.string(t.parent)
        out.string(t.child)
        out.pack("3d", *(float(v) for v in t.translation), size=8)
        out.pack("4d", *(float(v) for v in t.rotation), size=8)
    return bytes(out.buf)


class _In:
    def __init__(self, data: bytes):
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
            raise ValueError("not a CDR payload (unknown encapsulation header)")
        self.data = data
        self.endian = "<" if data[1] == 1 else ">"
        self.pos = 4

    def unpack(self, fmt: str, size: int):
        self.pos += -(self.pos - 4) % size
        values = struct.unpack_from(self.endian + fmt, self.data, self.pos)
        self.pos += struct.calcsize(self.endian + fmt)
        return values

    def string(self) -> str:
        (n,) = self.unpack("I", 4)
        if n == 0 or self.pos + n > len(self.data):
            raise ValueError("truncated or malformed CDR string")
        s = self.data[self.pos:self.pos + n - 1].decode("utf-8")
        self.pos += n
        return s


def decode_tf_message(data: bytes) -> list[Transform]:
    """The transforms of a serialized ``tf2_msgs/msg/TFMessage`` (either byte order); ValueError if malformed."""
    inp = _In(bytes(data))
    try:
        (count,) = inp.unpack("I", 4)
        out = []
        for _ in range(count):
            sec, nsec = inp.unpack("iI", 4)
            parent = inp.string()
            child = inp.string()
            translation = inp.unpack("3d", 8)
            rotation = inp.unpack("4d", 8)
            out.append(Transform(sec * 1_000_000_000 + nsec, parent, child, translation, rotation))
    except struct.error:
        raise ValueError("truncated TFMessage") from None
    return out
