"""Writers of lab camera/DAQ files for tests/test_lab_files.py, from a synthetic recording's arrays.

MRAW 8/16-bit: pyMRAW.save_mraw. pyMRAW cannot write 12-bit packed MRAW: :func:`write_mraw12` is a
documented minimal writer (two pixels in three bytes, big-nibble first, the layout pyMRAW's
``nb_read_uint12`` decodes). pycine cannot write CINE files at all: :func:`write_cine` fills
pycine's own header structures (CINEFILEHEADER, BITMAPINFOHEADER, SETUP) and lays the file out as
the format defines (headers, frame offset table, per frame an 8-byte annotation block + the
rows bottom-up). TDMS: npTDMS's TdmsWriter.
"""

from __future__ import annotations

import ctypes
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def write_mraw(images: np.ndarray, header_path: Path, bits: int, fps: float, effective_bits: int | None = None,
               start_frame: int = 0) -> Path:
    """``images`` (n, h, w) as video.mraw + video.cih (pyMRAW.save_mraw, 8 or 16 bit)."""
    import pyMRAW

    info = {"Record Rate(fps)": f"{fps:g}", "Start Frame": str(start_frame),
            "EffectiveBit Depth": effective_bits or bits}
    pyMRAW.save_mraw(images, str(header_path.with_suffix(".mraw")), bit_depth=bits, info_dict=info)
    return header_path.with_suffix(".cih")


def write_mraw12(images: np.ndarray, header_path: Path, fps: float) -> Path:
    """``images`` (n, h, w, values < 4096) as a 12-bit packed MRAW: minimal writer (pyMRAW cannot write 12 bit)."""
    import pyMRAW

    n, h, w = images.shape
    pyMRAW.save_mraw(images[:1].astype(np.uint16) & 0xFF, str(header_path.with_suffix(".mraw")), bit_depth=16,
                     info_dict={"Record Rate(fps)": f"{fps:g}", "Total Frame": n, "Original Total Frame": n,
                                "Color Bit": 12, "EffectiveBit Depth": 12})  # the header; data replaced below
    flat = images.astype(np.uint16).reshape(-1, 2)
    a, b = flat[:, 0], flat[:, 1]
    packed = np.column_stack([a >> 4, ((a & 0xF) << 4) | (b >> 8), b & 0xFF]).astype(np.uint8)
    header_path.with_suffix(".mraw").write_bytes(packed.tobytes())
    return header_path.with_suffix(".cih")


@dataclass(frozen=True, kw_only=True)
class CineClock:
    """The timing a CINE file records: the first image's number, the trigger's wall time (Unix s) and,
    optionally, one time stamp per image (s after the trigger)."""

    first_image_no: int = 0
    trigger_unix_s: float = 0.0
    time_stamps_s: np.ndarray | None = None


def write_cine(images: np.ndarray, path: Path, fps: float, real_bpp: int, *, clock: CineClock = CineClock(),
               black_white: tuple[int, int] | None = None, cfa: int = 0) -> Path:
    """``images`` (n, h, w) uint8 (8 bit) or uint16 (16-bit storage, ``real_bpp`` significant bits) as CINE.

    ``clock.time_stamps_s``: one per image, seconds after ``clock.trigger_unix_s``, written as the tagged
    "time only" block (type 1002: a block
    header of size, type, reserved, then TIME64 = uint32 fractions of 2**-32 s, uint32 seconds) between
    the setup (whose ``Length`` says where it ends) and the frame offset table. ``black_white``: the
    setup's BlackLevel/WhiteLevel (display levels; default 0 and full scale). ``cfa``: the setup's colour
    filter array code (0: grayscale).
    """
    from pycine import cine

    first_image_no, trigger_unix_s, time_stamps_s = clock.first_image_no, clock.trigger_unix_s, clock.time_stamps_s

    n, h, w = images.shape
    bits = 8 if images.dtype == np.uint8 else 16
    cfh, bih, setup = cine.CINEFILEHEADER(), cine.BITMAPINFOHEADER(), cine.SETUP()
    tagged = b""
    if time_stamps_s is not None:  # ticks of 2**-32 s in integers: a Unix time in float64 resolves 0.24 us only
        trigger_ticks = int(trigger_unix_s) * 2 ** 32 + int(round((trigger_unix_s - int(trigger_unix_s)) * 2 ** 32))
        ticks = trigger_ticks + np.round(np.asarray(time_stamps_s, dtype=np.float64) * 2 ** 32).astype(np.int64)
        pairs = np.stack([ticks % 2 ** 32, ticks // 2 ** 32], axis=1).astype("<u4")
        tagged = struct.pack("<IHH", 8 + pairs.nbytes, 1002, 0) + pairs.tobytes()
    cfh.Type, cfh.Headersize, cfh.Version = 0x4943, ctypes.sizeof(cfh), 1
    cfh.FirstImageNo, cfh.ImageCount, cfh.TotalImageCount, cfh.FirstMovieImage = first_image_no, n, n, first_image_no
    cfh.OffImageHeader = ctypes.sizeof(cfh)
    cfh.OffSetup = cfh.OffImageHeader + ctypes.sizeof(bih)
    cfh.OffImageOffsets = cfh.OffSetup + ctypes.sizeof(setup) + len(tagged)
    cfh.TriggerTime.seconds = int(trigger_unix_s)
    cfh.TriggerTime.fractions = int(round((trigger_unix_s - int(trigger_unix_s)) * 2 ** 32))
    bih.biSize, bih.biWidth, bih.biHeight, bih.biPlanes = ctypes.sizeof(bih), w, h, 1
    bih.biBitCount, bih.biCompression, bih.biSizeImage = bits, 0, w * h * bits // 8
    setup.FrameRate, setup.FrameRate16 = int(fps), int(fps) & 0xFFFF
    black, white = black_white if black_white is not None else (0, 2 ** real_bpp - 1)
    setup.RealBPP, setup.BlackLevel, setup.WhiteLevel = real_bpp, black, white
    setup.ImWidth, setup.ImHeight, setup.CFA = w, h, cfa
    setup.Length = ctypes.sizeof(setup)
    first = cfh.OffImageOffsets + 8 * n
    block = 8 + bih.biSizeImage
    with path.open("wb") as f:
        f.write(bytes(cfh))
        f.write(bytes(bih))
        f.write(bytes(setup))
        f.write(tagged)
        f.write(struct.pack(f"<{n}q", *(first + k * block for k in range(n))))
        for image in images:
            f.write(struct.pack("<II", 8, bih.biSizeImage))
            f.write(np.ascontiguousarray(np.flipud(image)).astype("<u2" if bits == 16 else np.uint8).tobytes())
    return path


def write_tdms(path: Path, upper: np.ndarray, lower: np.ndarray, dt_s: float, start: np.datetime64,
               group: str = "accel", names: tuple[str, str] = ("upper_plate", "lower_plate")) -> Path:
    """Two waveform channels (m/s^2) with wf_increment, wf_start_time, wf_start_offset, wf_samples (npTDMS)."""
    from nptdms import ChannelObject, TdmsWriter

    props = {"wf_increment": dt_s, "wf_start_time": start, "wf_start_offset": 0.0, "wf_samples": len(upper),
             "unit_string": "m/s^2"}
    with TdmsWriter(str(path)) as writer:
        writer.write_segment([ChannelObject(group, names[0], upper, properties=props),
                              ChannelObject(group, names[1], lower, properties=props)])
    return path
