"""vibro_msgs/DicFrame written straight to its serialized bytes (CDR), for ``publish(bytes)``.

No rclpy here. Building a DicFrame message and publishing it makes rclpy convert the Python object to C and
serialize it, per frame; ``dic_tracker`` instead writes the CDR bytes itself (:class:`DicFrameEncoder`, a few
``struct`` packs) and publishes them raw: the bytes are exactly those ``rclpy.serialization.serialize_message``
gives for the same DicFrame but for the alignment padding, which rmw leaves uninitialised and this writes as
zeros (tests/test_raw_image.py; the node checks it once at start, :meth:`DicFrameEncoder.matches`, and falls back
to messages if not, e.g. after DicFrame.msg changed). The layout (little-endian plain
CDR, XCDR1, each field aligned to its size counted from byte 4, after the encapsulation header; offsets from byte
4)::

     0  header.stamp.sec int32, .nanosec uint32     8  header.frame_id string ("camera": 4 + 7 bytes)
    24  frame_index uint64                         32  t_s, ball_mm, structure_mm float64
    56  ball_valid_points, ball_mesh_points, structure_valid_points, structure_mesh_points uint32
    72  ball_mean_zncc, structure_mean_zncc float32 80  lost bool
        status string (4-aligned), reference_frame_index uint64 (8-aligned), run_id string (4-aligned),
        ball_rot_rad, ball_rot_std_rad float64 (8-aligned)

The fixed part up to ``lost`` is one ``struct``; the strings (the status, the run id) come after it.
"""

from __future__ import annotations

import math
import struct

from vibro_io.dictrack import FrameTrack
from vibro_ros.lab_clock import NS_PER_S, stamp_ns_from_data_time

#: the header's frame_id of every DicFrame (vibro_ros.convert.frame_track_to_message)
FRAME_ID = "camera"
_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE, no options
_FIXED = struct.Struct("<iI I7s 5x Q ddd IIII ff ?")  # offsets 0-81 from byte 4: header .. lost
_U32 = struct.Struct("<I")
_Q = struct.Struct("<Q")
_DD = struct.Struct("<dd")
_ZEROS = bytes(8)
assert _FIXED.size == 81 and len(FRAME_ID) + 1 == 7


def _cdr_string(text: str, pos: int) -> tuple[bytes, int]:
    """A CDR string (4-aligned uint32 length with the NUL, the bytes, the NUL) written at relative position
    ``pos``, with the padding before it: its bytes and the position after it."""
    data = text.encode()
    pad = -pos % 4
    out = _ZEROS[:pad] + _U32.pack(len(data) + 1) + data + b"\0"
    return out, pos + len(out)


class DicFrameEncoder:
    """Writes the CDR bytes of one DicFrame per tracked frame; the mesh sizes and the lab clock's origin are fixed
    per tracker. :meth:`encode` takes what :func:`vibro_ros.convert.frame_track_to_message` takes."""

    def __init__(self, mesh_points: tuple[int, int], origin_ns: int = 0):
        self.mesh_points = (int(mesh_points[0]), int(mesh_points[1]))
        self.origin_ns = int(origin_ns)
        self._run_id: str | None = None
        self._tail_cache: dict[tuple[str, int], bytes] = {}

    def encode(self, row: FrameTrack, status: str = "", reference_frame_index: int = 0, run_id: str = "") -> bytes:
        t_s = row.t_s
        if t_s is not None and math.isfinite(t_s):  # an unknown time leaves the stamp at 0, as the message does
            sec, nanosec = divmod(stamp_ns_from_data_time(self.origin_ns, t_s), NS_PER_S)
        else:
            sec = nanosec = 0
        fixed = _FIXED.pack(sec, nanosec, 7, b"camera\0", row.frame, t_s, row.ball_mm, row.structure_mm,
                            row.ball_valid, self.mesh_points[0], row.structure_valid, self.mesh_points[1],
                            row.ball_zncc, row.structure_zncc, bool(row.lost))
        head, pos = _cdr_string(status, _FIXED.size) if status else (b"\0\0\0\x01\0\0\0\0", 89)
        tail = self._tail(reference_frame_index, run_id, pos)
        rot = _DD.pack(float(row.ball_rot_rad), float(row.ball_rot_std_rad))
        return b"".join((_ENCAPSULATION, fixed, head, tail, rot))

    def _tail(self, reference_frame_index: int, run_id: str, pos: int) -> bytes:
        """reference_frame_index, run_id and the padding before ball_rot_rad, from relative position ``pos``
        (its residue mod 8 is all that matters: cached per residue, reference frame and run id)."""
        key = (run_id, int(reference_frame_index), pos % 8)
        out = self._tail_cache.get(key)
        if out is None:
            start = pos
            pad = -pos % 8
            pos += pad
            parts = [_ZEROS[:pad], _Q.pack(int(reference_frame_index))]
            pos += 8
            text, pos = _cdr_string(run_id, pos)
            parts.append(text)
            parts.append(_ZEROS[:-pos % 8])
            out = b"".join(parts)
            assert len(out) == pos + (-pos % 8) - start
            if len(self._tail_cache) > 64:  # a run id or a reference frame changes once or twice in a run
                self._tail_cache.clear()
            self._tail_cache[key] = out
        return out

    def matches(self, serialize, deserialize, message) -> bool:
        """Whether :meth:`encode` writes the DicFrame that ``message(row, status, reference_frame_index, run_id)``
        builds (:func:`vibro_ros.convert.frame_track_to_message` bound to this tracker's mesh and origin): as many
        bytes as ``serialize`` of it gives, and both read back by ``deserialize`` (bytes -> message) with every
        field equal (NaN as NaN), for a few rows: statuses and run ids of every length modulo 8, a lost frame (NaN), an
        unknown time. (Bytes equal but for the padding: rmw leaves the alignment padding uninitialised.)"""
        nan = math.nan
        rows = [FrameTrack(frame=12345, t_s=12.345, ball_mm=-0.125, structure_mm=0.0625, ball_valid=40,
                           structure_valid=90, ball_zncc=0.99871, structure_zncc=0.5, lost=False,
                           ball_rot_rad=1.25e-3, ball_rot_std_rad=3e-5),
                FrameTrack(frame=7, t_s=nan, ball_mm=nan, structure_mm=nan, ball_valid=0, structure_valid=0,
                           ball_zncc=nan, structure_zncc=nan, lost=True)]
        for row in rows:
            for n in range(9):
                for run_id in ("", "r" * (n + 3)):
                    status, ref = "s" * n, n
                    want = serialize(message(row, status, ref, run_id))
                    got = self.encode(row, status, ref, run_id)
                    if len(got) != len(want) or not same_message(deserialize(got), deserialize(want)):
                        return False
        return True


def same_message(a, b) -> bool:
    """Two ROS messages of one type with every field equal, NaN equal to NaN (nested messages compared the same
    way; ``get_fields_and_field_types`` names the fields)."""
    if type(a) is not type(b):
        return False
    for name in type(a).get_fields_and_field_types():
        x, y = getattr(a, name), getattr(b, name)
        if hasattr(type(x), "get_fields_and_field_types"):
            if not same_message(x, y):
                return False
        elif isinstance(x, float) and isinstance(y, float):
            if not (x == y or (math.isnan(x) and math.isnan(y))):
                return False
        elif x != y:
            return False
    return True
