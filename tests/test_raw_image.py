"""dic_tracker's serialized-message paths (issue 41): sensor_msgs/Image read in place from its CDR bytes
(vibro_dic.raw_image), DicFrame written as CDR bytes (vibro_dic.dic_frame_cdr). Both against rclpy's own
serialization (rclpy.serialization), no DDS."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from vibro_dic.raw_image import ImageDecodeError, cdr_stamp_ns, decode_image


def _image(pixels: np.ndarray, encoding: str, frame_id: str = "camera", sec: int = 1_764_000_123,
           nanosec: int = 987_654_321, pad: int = 0, big: bool = False):
    """An Image of ``pixels`` (rows ``pad`` bytes longer than needed), big-endian data when ``big``."""
    from sensor_msgs.msg import Image

    h, w = pixels.shape
    data = pixels.astype(pixels.dtype.newbyteorder(">" if big else "<"))
    step = w * pixels.itemsize + pad
    rows = np.zeros((h, step), dtype=np.uint8)
    rows[:, : w * pixels.itemsize] = data.view(np.uint8).reshape(h, -1)
    msg = Image(height=h, width=w, encoding=encoding, is_bigendian=int(big), step=step, data=rows.tobytes())
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


def _serialize(msg) -> bytes:
    from rclpy.serialization import serialize_message

    return serialize_message(msg)


@pytest.mark.parametrize("encoding,dtype", [("mono8", np.uint8), ("8UC1", np.uint8), ("mono16", np.uint16),
                                            ("16UC1", np.uint16)])
@pytest.mark.parametrize("width", [1, 3, 5, 160, 161])
def test_serialized_images_read_back_equal(encoding: str, dtype, width: int) -> None:
    """Every frame_id length 0-9 (the fields after it at every alignment), odd and even widths, rows with and
    without padding: the pixels (a view into the bytes, not a copy) and the stamp are those of the message."""
    rng = np.random.default_rng(width)
    top = np.iinfo(dtype).max
    for n in range(10):
        for pad in (0, 3):
            pixels = rng.integers(0, top, size=(7, width), dtype=dtype, endpoint=True)
            msg = _image(pixels, encoding, frame_id="f" * n, sec=-3 + n, nanosec=n * 111_111_111, pad=pad)
            raw = _serialize(msg)
            img = decode_image(raw)
            got = img.pixels()
            np.testing.assert_array_equal(got, pixels)
            assert np.shares_memory(got, np.frombuffer(raw, dtype=np.uint8))  # read in place
            assert img.stamp_ns == cdr_stamp_ns(raw) == (-3 + n) * 1_000_000_000 + n * 111_111_111
            assert (img.frame_id, img.encoding, img.height, img.width) == ("f" * n, encoding, 7, width)
            assert img.step == width * pixels.itemsize + pad and not img.is_bigendian


def test_big_endian_mono16_pixels_read_as_their_values() -> None:
    pixels = np.arange(4 * 5, dtype=np.uint16).reshape(4, 5) * 3001
    img = decode_image(_serialize(_image(pixels, "mono16", big=True)))
    assert img.is_bigendian
    np.testing.assert_array_equal(img.pixels(), pixels)
    native = img.native()
    assert native.dtype == np.uint16 and native.dtype.isnative
    np.testing.assert_array_equal(native, pixels)
    f32 = np.empty(pixels.shape, dtype=np.float32)
    np.copyto(f32, img.pixels())  # as dic_tracker converts into its buffer
    np.testing.assert_array_equal(f32, pixels.astype(np.float32))


def test_the_same_pixels_as_the_message_path() -> None:
    """What dic_tracker_node.image_array makes of the deserialized message (the path before)."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    from vibro_dic.dic_tracker_node import image_array

    rng = np.random.default_rng(3)
    for pixels, encoding, big in ((rng.integers(0, 255, (9, 13), dtype=np.uint8), "mono8", False),
                                  (rng.integers(0, 65535, (9, 13), dtype=np.uint16), "mono16", True)):
        raw = _serialize(_image(pixels, encoding, frame_id="cam", pad=2, big=big))
        np.testing.assert_array_equal(decode_image(raw).native(), image_array(deserialize_message(raw, Image)))


def test_every_truncation_is_refused_naming_a_field() -> None:
    raw = _serialize(_image(np.arange(12, dtype=np.uint8).reshape(3, 4), "mono8", frame_id="cam0"))
    decode_image(raw)
    fields = set()
    for n in range(len(raw)):
        with pytest.raises(ImageDecodeError, match=r"^image \S+") as err:
            decode_image(raw[:n])
        fields.add(str(err.value).split(":")[0].split()[1])
    # each field in turn is where the bytes end
    assert {"encapsulation", "header.stamp", "header.frame_id", "height/width", "encoding", "is_bigendian",
            "step", "data"} <= fields, fields
    with pytest.raises(ValueError, match="no header stamp"):
        cdr_stamp_ns(raw[:11])


def _field_offsets(raw: bytes) -> dict[str, int]:
    """Offsets of a serialized Image's fields, read with struct (independent of decode_image's bookkeeping)."""
    (n,) = struct.unpack_from("<I", raw, 12)
    pos = 16 + n
    pos += -pos % 4
    out = {"height": pos, "width": pos + 4, "encoding": pos + 8}
    (m,) = struct.unpack_from("<I", raw, pos + 8)
    pos += 12 + m
    out["is_bigendian"] = pos
    pos += 1
    pos += -pos % 4
    out["step"], out["data"] = pos, pos + 4
    return out


def _patched(raw: bytes, offset: int, fmt: str, value) -> bytes:
    b = bytearray(raw)
    struct.pack_into(fmt, b, offset, value)
    return bytes(b)


def test_damaged_fields_are_refused_by_name() -> None:
    pixels = np.arange(6 * 8, dtype=np.uint8).reshape(6, 8)
    raw = _serialize(_image(pixels, "mono8", frame_id="camera"))
    at = _field_offsets(raw)
    bad = {
        "encapsulation: big-endian CDR": b"\x00\x00" + raw[2:],
        "encapsulation: representation 0x0007": b"\x00\x07" + raw[2:],
        "header.frame_id: the message ends": _patched(raw, 12, "<I", 10_000),
        "header.frame_id: a string of 7 bytes not ending in NUL": raw[:22] + b"X" + raw[23:],
        "encoding 'rgb8' not supported": _serialize(_image(pixels, "rgb8")),
        "encoding 'mono8X' not supported": raw[:at["encoding"]] + struct.pack("<I", 7) + b"mono8X\0" + raw[
            at["encoding"] + 10:at["is_bigendian"]] + raw[at["is_bigendian"]:],
        "is_bigendian: 7": _patched(raw, at["is_bigendian"], "<B", 7),
        "step: 7 bytes, shorter than a row of 8": _patched(raw, at["step"], "<I", 7),
        "data: 47 bytes, 8x6 with step 8 needs 48": _patched(raw, at["data"], "<I", 47)[:-1],
        "data: 49 bytes announced, 48 in the message": _patched(raw, at["data"], "<I", 49),
        "height/width: 8x0, empty": _patched(raw, at["height"], "<I", 0),
    }
    for what, damaged in bad.items():
        with pytest.raises(ImageDecodeError) as err:
            decode_image(damaged)
        assert str(err.value).startswith(f"image {what}"), (what, str(err.value))


# ------------------------------------------------------------------------------------------------ DicFrame out
def _rows():
    from vibro_io.dictrack import FrameTrack

    nan = math.nan
    rng = np.random.default_rng(7)
    for k in range(40):
        lost = k % 5 == 0
        yield FrameTrack(frame=int(rng.integers(0, 2**40)), t_s=float(rng.uniform(-1, 1e4)) if k % 7 else nan,
                         ball_mm=nan if lost else float(rng.normal()),
                         structure_mm=nan if lost else float(rng.normal()),
                         ball_valid=int(rng.integers(0, 100)), structure_valid=int(rng.integers(0, 400)),
                         ball_zncc=nan if lost else float(rng.uniform(-1, 1)),
                         structure_zncc=nan if lost else float(rng.uniform(0, 1)), lost=lost,
                         ball_rot_rad=float(rng.normal()) if k % 3 else nan,
                         ball_rot_std_rad=float(rng.uniform()) if k % 3 else nan)


def test_dicframe_bytes_read_back_as_rclpys() -> None:
    """The encoder's bytes deserialize to the DicFrame rclpy's serialization of the message gives, field for field
    (NaN as NaN; zncc rounded to float32 by both), at every status and run id length (UTF-8 included) and
    reference frame, and have its length."""
    from rclpy.serialization import deserialize_message, serialize_message

    from vibro_dic.dic_frame_cdr import DicFrameEncoder, same_message
    from vibro_dic.dic_tracker_node import dic_message
    from vibro_msgs.msg import DicFrame

    origin = 1_764_000_000_123_456_789
    enc = DicFrameEncoder((45, 97), origin)
    statuses = ["", "x", "ball: too few valid points (2 of 9, need 3)", "é", "ümlaut ±0.5 px", "s" * 13]
    for i, row in enumerate(_rows()):
        for status in statuses:
            for run_id in ("", "r", "run_20261127_1", "ß" * (i % 5)):
                ref = i * 17
                want = serialize_message(dic_message(row, (45, 97), status, ref, run_id, origin))
                got = enc.encode(row, status, ref, run_id)
                assert len(got) == len(want)
                back = deserialize_message(got, DicFrame)
                assert same_message(back, deserialize_message(want, DicFrame)), (row, status, run_id)
                assert (back.status, back.run_id, back.reference_frame_index) == (status, run_id, ref)


def test_the_start_check_catches_a_layout_that_differs() -> None:
    """dic_tracker publishes raw only when DicFrameEncoder.matches holds: true for the real message, false for
    a DicFrame it would write wrong (here: another mesh size, another clock origin)."""
    from rclpy.serialization import deserialize_message, serialize_message

    from vibro_dic.dic_frame_cdr import DicFrameEncoder
    from vibro_dic.dic_tracker_node import dic_message
    from vibro_msgs.msg import DicFrame

    def check(enc: DicFrameEncoder, mesh: tuple[int, int], origin: int) -> bool:
        return enc.matches(serialize_message, lambda b: deserialize_message(b, DicFrame),
                           lambda row, status, ref, run_id: dic_message(row, mesh, status, ref, run_id, origin))

    assert check(DicFrameEncoder((0, 0), 5), (0, 0), 5)
    assert not check(DicFrameEncoder((0, 1), 5), (0, 0), 5)
    assert not check(DicFrameEncoder((0, 0), 6), (0, 0), 5)
