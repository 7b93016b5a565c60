"""sensor_msgs/Image read straight from its serialized bytes (CDR), without deserializing the message.

No rclpy here. ``dic_tracker`` subscribes to its images raw (``create_subscription(..., raw=True)``): the
executor hands it the CDR bytes of each Image, and :func:`decode_image` reads the few fields it needs and gives the
pixels as a NumPy view into those bytes (no copy). The layout, as rmw_fastrtps writes it (little-endian plain CDR,
XCDR1; the alignment of each field is counted from byte 4, after the encapsulation header)::

    offset  field                      type
         0  encapsulation              uint16 representation id, big-endian on the wire (0x0001 = CDR_LE),
                                       uint16 options
         4  header.stamp.sec           int32
         8  header.stamp.nanosec       uint32
        12  header.frame_id            string: uint32 length n (its bytes + the NUL), then n bytes
         a  height                     uint32, 4-aligned
            width                      uint32
            encoding                   string: uint32 length m, then m bytes
         b  is_bigendian               uint8
         c  step                       uint32, 4-aligned (1-3 bytes of padding after is_bigendian)
            data                       sequence<uint8>: uint32 length, then the pixel bytes (row r at r * step)

Every field is checked: a message cut short, an encoding other than mono8/8UC1 (uint8) or mono16/16UC1 (uint16), a
step shorter than a row, data shorter than step x height, is_bigendian other than 0/1, or an encapsulation other
than little-endian CDR raise :class:`ImageDecodeError` (a :class:`vibro_model.errors.RecordingError`) naming the
field; the tracker answers that image as lost with the message as its reason. ``is_bigendian`` = 1 is read
(mono16 byte-swapped into native uint16, as :func:`vibro_dic.dic_tracker_node.image_array` does).

:func:`cdr_stamp_ns` reads only the stamp (12 bytes), in either CDR byte order: what the live tracker's catch-up
needs of every image waiting in its queue (:mod:`vibro_dic.catch_up`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from vibro_model.errors import RecordingError

#: encoding -> pixel type (little-endian; big-endian mono16 when ``is_bigendian``)
DTYPES = {"mono8": np.dtype(np.uint8), "8UC1": np.dtype(np.uint8), "mono16": np.dtype("<u2"),
          "16UC1": np.dtype("<u2")}
_BIG = {np.dtype("<u2"): np.dtype(">u2")}
#: the CDR_LE representation id: bytes 0-1 of the encapsulation header
CDR_LE = b"\x00\x01"
_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_HW = struct.Struct("<II")


class ImageDecodeError(RecordingError):
    """A serialized sensor_msgs/Image that cannot be read as a mono8/mono16 image; the message names the field."""


def cdr_stamp_ns(raw: bytes) -> int:
    """The header stamp (ns) of a serialized message whose first field is a std_msgs/Header (sensor_msgs/Image):
    CDR encapsulation (4 bytes: representation id, options), then int32 sec and uint32 nanosec in its byte
    order. Reads 12 bytes; the image itself is never deserialized. ValueError when the bytes are too few."""
    if len(raw) < 12:
        raise ValueError(f"a serialized message of {len(raw)} bytes has no header stamp")
    order = "little" if raw[1] & 1 else "big"  # 0x0001 CDR_LE, 0x0000 CDR_BE (and their PL_ variants 2/3)
    sec = int.from_bytes(raw[4:8], order, signed=True)
    nanosec = int.from_bytes(raw[8:12], order)
    return sec * 1_000_000_000 + nanosec


@dataclass(slots=True)
class RawImage:
    """The fields of a serialized Image the tracker reads, and its pixels as a view into the bytes
    (:meth:`pixels`). ``offset``: where the pixel data begins in ``raw``; ``size``: its length (bytes);
    ``dtype``: the pixels' type in the message's byte order."""

    raw: bytes
    sec: int
    nanosec: int
    frame_id: str
    height: int
    width: int
    encoding: str
    is_bigendian: bool
    step: int
    offset: int
    size: int
    dtype: np.dtype

    @property
    def stamp_ns(self) -> int:
        return self.sec * 1_000_000_000 + self.nanosec

    def pixels(self) -> np.ndarray:
        """(height, width) array of the pixels: a read-only view into the message's bytes (rows ``step`` bytes
        apart), in the message's byte order (``>u2`` for a big-endian mono16: :meth:`native` converts)."""
        return np.ndarray((self.height, self.width), dtype=self.dtype, buffer=self.raw, offset=self.offset,
                          strides=(self.step, self.dtype.itemsize))

    def native(self) -> np.ndarray:
        """The pixels in the machine's uint8/uint16 (a copy only for big-endian mono16)."""
        px = self.pixels()
        return px if px.dtype.isnative else px.astype(px.dtype.newbyteorder("="))


def _need(raw: bytes, end: int, field: str) -> None:
    if end > len(raw):
        raise ImageDecodeError(f"image {field}: the message ends at byte {len(raw)}, the field needs {end} "
                               "(truncated)")


def _string(raw: bytes, pos: int, field: str) -> tuple[str, int]:
    """A CDR string at ``pos`` (4-aligned): its text and the position after it."""
    _need(raw, pos + 4, field)
    (n,) = _U32.unpack_from(raw, pos)
    pos += 4
    _need(raw, pos + n, field)
    if n and raw[pos + n - 1] != 0:
        raise ImageDecodeError(f"image {field}: a string of {n} bytes not ending in NUL (damaged)")
    try:
        text = raw[pos:pos + n - 1].decode() if n else ""
    except UnicodeDecodeError:
        raise ImageDecodeError(f"image {field}: not UTF-8 (damaged)") from None
    return text, pos + n


def _align4(pos: int) -> int:
    """The next 4-aligned position (counted from the encapsulation header's end, byte 4: the same residue)."""
    return (pos + 3) & ~3


def decode_image(raw: bytes) -> RawImage:
    """The Image in ``raw`` (its CDR bytes, as a raw subscription or ``serialize_message`` gives them), checked
    field by field; :class:`ImageDecodeError` naming the field otherwise."""
    if len(raw) < 4:
        raise ImageDecodeError(f"image encapsulation: a message of {len(raw)} bytes (truncated)")
    if raw[0:2] != CDR_LE:
        rep = int.from_bytes(raw[0:2], "big")
        what = "big-endian CDR" if rep in (0, 2) else "representation"
        raise ImageDecodeError(f"image encapsulation: {what} 0x{rep:04x} not supported (little-endian CDR, "
                               "0x0001, expected)")
    _need(raw, 12, "header.stamp")
    sec, nanosec = _STAMP.unpack_from(raw, 4)
    frame_id, pos = _string(raw, 12, "header.frame_id")
    pos = _align4(pos)
    _need(raw, pos + 8, "height/width")
    height, width = _HW.unpack_from(raw, pos)
    encoding, pos = _string(raw, pos + 8, "encoding")
    dtype = DTYPES.get(encoding)
    if dtype is None:
        raise ImageDecodeError(f"image encoding {encoding!r} not supported (mono8 or mono16)")
    _need(raw, pos + 1, "is_bigendian")
    big = raw[pos]
    if big > 1:
        raise ImageDecodeError(f"image is_bigendian: {big}, must be 0 or 1 (damaged)")
    pos = _align4(pos + 1)
    _need(raw, pos + 4, "step")
    (step,) = _U32.unpack_from(raw, pos)
    _need(raw, pos + 8, "data")
    (size,) = _U32.unpack_from(raw, pos + 4)
    offset = pos + 8
    if offset + size > len(raw):
        raise ImageDecodeError(f"image data: {size} bytes announced, {len(raw) - offset} in the message (truncated)")
    if height == 0 or width == 0:
        raise ImageDecodeError(f"image height/width: {width}x{height}, empty")
    if step < width * dtype.itemsize:
        raise ImageDecodeError(f"image step: {step} bytes, shorter than a row of {width} x {dtype.itemsize} bytes")
    if size < step * height:
        raise ImageDecodeError(f"image data: {size} bytes, {width}x{height} with step {step} needs "
                               f"{step * height}")
    if big and dtype.itemsize > 1:
        dtype = _BIG[dtype]
    return RawImage(raw, sec, nanosec, frame_id, height, width, encoding, bool(big), step, offset, size, dtype)
