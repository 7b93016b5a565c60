"""High-speed camera files: Photron MRAW (+ .cih/.cihx header) and Phantom CINE, one frame at a time.

Readers: pyMRAW (header parsing and checks, and its 12-bit unpacker applied to one frame at a
time) and pycine (header structures, frame offsets, 16-bit and packed frames). Memory stays
constant whatever the length: each frame is mapped or read from the file on its own
(pyMRAW's ``load_video`` maps the whole file and decodes a 12-bit file whole; it is not used).

Pixel convention (the same for every source): 8-bit data is delivered as ``uint8``; deeper data
as ``uint16`` with its significant bits at the top, i.e. ``value << (16 - effective_bits)``, so a
12-bit and a 16-bit file of the same scene give the same numbers up to the lost low bits.

Header values (:class:`CameraHeader`): frame rate (fps), the time of frame 0 relative to the
trigger (``t0_s``, from the MRAW "Start Frame" or the CINE ``FirstImageNo``) and, for CINE, the
wall-clock time of frame 0 (``TriggerTime`` + t0_s). Neither format's header, as these libraries
read it, holds a scale in the scene (CINE's ``biXPelsPerMeter`` is the sensor's pixel pitch), so
``camera.mm_per_px`` always comes from rig.yaml. :func:`merge_camera_header` reconciles the
header with rig.yaml.
"""

from __future__ import annotations

import logging
import math
import struct
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from vibro_model.errors import FrameError, RigError

log = logging.getLogger(__name__)

MRAW_HEADER_SUFFIXES = (".cihx", ".cih")
CINE_SUFFIXES = (".cine",)
CAMERA_FILE_SUFFIXES = MRAW_HEADER_SUFFIXES + CINE_SUFFIXES

#: Relative difference of rig.yaml's camera.fps from the header's beyond which the recording is refused.
FPS_RELATIVE_TOLERANCE = 1e-6
#: rig.yaml's camera.start_time_unix_s further than this from the header's draws a warning (s).
START_TIME_TOLERANCE_S = 1e-3


@dataclass(frozen=True)
class CameraHeader:
    """What a camera file's header says: fps (frames/s), t0_s (s, frame 0 relative to the trigger, or None),
    start_time_unix_s (wall time of frame 0, Unix s, or None), frame count and size, bits per pixel."""

    path: Path
    fps: float
    t0_s: float | None
    start_time_unix_s: float | None
    n_frames: int
    height_px: int
    width_px: int
    bits: int


def _shifted(image: np.ndarray, effective_bits: int, where: str) -> np.ndarray:
    """``image`` (uint16 holding ``effective_bits`` low bits) moved to the top of 16 bits; FrameError if wider."""
    if effective_bits >= 16:
        return image
    if int(image.max(initial=0)) >> effective_bits:
        raise FrameError(f"{where}: pixel value {int(image.max())} exceeds the header's {effective_bits}-bit depth")
    return image << np.uint16(16 - effective_bits)


class _CameraFile:
    """What every camera file reader shares: ``header`` (:class:`CameraHeader`) and ``bits`` per pixel."""

    header: CameraHeader
    bits: int

    @property
    def dtype(self) -> np.dtype:
        """The pixel type frames are returned in: uint8 for 8-bit files, uint16 (MSB-aligned) otherwise."""
        return np.dtype(np.uint8 if self.bits == 8 else np.uint16)

    def __len__(self) -> int:
        return self.header.n_frames


class MrawFile(_CameraFile):
    """A Photron MRAW file read through its .cih/.cihx header (``path``: the header file)."""

    _REQUIRED = ("Record Rate(fps)", "Total Frame", "Image Width", "Image Height", "Color Bit", "File Format",
                 "EffectiveBit Depth", "EffectiveBit Side")

    def __init__(self, header_path: str | Path):
        import pyMRAW

        self._unpack12 = pyMRAW.nb_read_uint12
        self.header_path = Path(header_path)
        self.path = self.header_path.with_suffix(".mraw")
        cih = self._read_cih(pyMRAW)
        n, h, w = cih["Total Frame"], cih["Image Height"], cih["Image Width"]
        self.bits = cih["Color Bit"]
        self.effective_bits = 8 if self.bits == 8 else min(int(cih["EffectiveBit Depth"]), 16)
        self.higher = str(cih["EffectiveBit Side"]).lower() == "higher"
        if self.bits == 12 and (h * w) % 2:
            raise FrameError(f"{self.header_path}: a 12-bit MRAW needs an even pixel count per frame, got {w}x{h}")
        self.frame_bytes = h * w * self.bits // 8
        fps = float(cih["Record Rate(fps)"])
        start = cih.get("Start Frame", self._cihx_start_frame())
        self.header = CameraHeader(self.header_path, fps, int(start) / fps if isinstance(start, int) else None,
                                   None, n, h, w, self.bits)
        self._check_size()

    def _read_cih(self, pyMRAW: Any) -> dict:
        if not self.path.is_file():
            raise FrameError(f"{self.header_path}: its image file {self.path.name} is missing")
        try:
            cih = pyMRAW.get_cih(str(self.header_path))
        except Exception as exc:  # pyMRAW raises bare Exception, KeyError, xml errors for a bad header
            raise FrameError(f"{self.header_path}: not a readable Photron header "
                             f"({type(exc).__name__}: {exc})") from None
        for key in self._REQUIRED:
            if key not in cih:
                raise FrameError(f"{self.header_path}: header key '{key}' missing")
        for key in ("Total Frame", "Image Width", "Image Height", "Color Bit", "EffectiveBit Depth"):
            if not isinstance(cih[key], int) or cih[key] <= 0:
                raise FrameError(f"{self.header_path}: header key '{key}' must be a positive integer, got {cih[key]!r}")
        rate = cih["Record Rate(fps)"]
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not rate > 0 or not math.isfinite(rate):
            raise FrameError(f"{self.header_path}: header key 'Record Rate(fps)' must be a positive number, "
                             f"got {rate!r}")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pyMRAW warns "Not 12bit image!" for every other depth
                pyMRAW.check_exceptions(cih)
        except Exception as exc:
            raise FrameError(f"{self.header_path}: unsupported Photron file (Color Bit {cih['Color Bit']}, "
                             f"File Format {cih['File Format']}, EffectiveBit Side {cih['EffectiveBit Side']}; "
                             f"pyMRAW reads 8-, 12- and 16-bit MRAW: {exc})") from None
        if str(cih["File Format"]).lower() != "mraw":
            raise FrameError(f"{self.header_path}: header 'File Format' is {cih['File Format']}, not MRAW")
        return cih

    def _cihx_start_frame(self) -> int | None:
        """frameInfo/startFrame of a .cihx (pyMRAW's dict leaves it out); None if absent or a .cih."""
        if self.header_path.suffix.lower() != ".cihx":
            return None
        import xml.etree.ElementTree as ET

        text = self.header_path.read_text(encoding="utf-8", errors="ignore")
        start, end = text.find("<cih>"), text.rfind("</cih>")
        try:
            value = ET.fromstring(text[start:end + 6]).findtext("frameInfo/startFrame")
            return None if value is None else int(value)
        except (ET.ParseError, ValueError):
            return None

    def _check_size(self) -> None:
        size = self.path.stat().st_size
        n = self.header.n_frames
        if size < n * self.frame_bytes:
            k = size // self.frame_bytes
            raise FrameError(
                f"{self.path}: truncated: {self.header_path.name} announces {n} frames of "
                f"{self.header.width_px}x{self.header.height_px} px at {self.bits} bits ({n * self.frame_bytes} "
                f"bytes) but the file holds {size} bytes; frame {k} is the first incomplete one")
        if size > n * self.frame_bytes:
            log.warning("%s: %d bytes after the %d frames %s announces are ignored", self.path,
                        size - n * self.frame_bytes, n, self.header_path.name)

    def read(self, k: int) -> np.ndarray:
        """Frame ``k`` (0-based) as a new array (file mapped for this frame only); FrameError naming file and frame."""
        h, w = self.header.height_px, self.header.width_px
        where = f"{self.path} frame {k}"
        try:
            raw = np.memmap(self.path, dtype=np.uint8, mode="r", offset=k * self.frame_bytes,
                            shape=(self.frame_bytes,))
        except (OSError, ValueError) as exc:
            raise FrameError(f"{where}: cannot read ({exc})") from None
        if self.bits == 8:
            return np.array(raw).reshape(h, w)
        if self.bits == 12:
            image = self._unpack12(raw).reshape(h, w)
            return image << np.uint16(4)
        image = np.array(raw).view("<u2").astype(np.uint16).reshape(h, w)
        return image if self.higher else _shifted(image, self.effective_bits, where)


class CineFile(_CameraFile):
    """A Phantom CINE file: pycine reads the header, the frame offsets and 16-bit/packed frames.

    pycine cannot decode 8-bit frames (it reads every uncompressed frame as 16-bit); for those a
    minimal reader does what the format defines: at the frame's offset, a 32-bit annotation size
    (annotation skipped), a 32-bit image size, then the rows bottom-up (flipped to top-down, as
    pycine does for 16 bits).
    """

    def __init__(self, path: str | Path):
        from pycine.file import read_header

        self.path = Path(path)
        try:
            hdr = read_header(str(self.path))
        except (OSError, ValueError, struct.error) as exc:
            raise FrameError(f"{self.path}: not a readable Phantom CINE file ({type(exc).__name__}: {exc})") from None
        self._hdr = hdr
        cfh, bih, setup = hdr["cinefileheader"], hdr["bitmapinfoheader"], hdr["setup"]
        if cfh.Type != 0x4943:  # "CI"
            raise FrameError(f"{self.path}: not a Phantom CINE file (no 'CI' signature)")
        w, h = int(bih.biWidth), abs(int(bih.biHeight))
        if w <= 0 or h <= 0:
            raise FrameError(f"{self.path}: header image size {w}x{h} px is not positive")
        if bih.biBitCount not in (8, 16) or bih.biCompression not in (0, 1):
            raise FrameError(f"{self.path}: {bih.biBitCount}-bit frames with compression {bih.biCompression} are "
                             "not supported (grayscale 8/16-bit or packed 10-bit CINE only; pycine reads those)")
        self.bits = 8 if bih.biBitCount == 8 else 16
        self.effective_bits = 8 if self.bits == 8 else (12 if bih.biCompression else int(setup.RealBPP))
        if not 8 <= self.effective_bits <= 16:
            raise FrameError(f"{self.path}: header RealBPP {setup.RealBPP} is not between 8 and 16 bits")
        fps = float(setup.FrameRate or setup.FrameRate16)
        if not fps > 0:
            raise FrameError(f"{self.path}: header frame rate (setup.FrameRate) is 0")
        t0_s = int(cfh.FirstImageNo) / fps
        trigger = cfh.TriggerTime.seconds + cfh.TriggerTime.fractions / 2.0 ** 32
        plausible = 946684800.0 <= trigger <= time.time() + 86400.0
        self.frame_bytes = (w * h * 10 // 8) if bih.biCompression else w * h * self.bits // 8
        self.header = CameraHeader(self.path, fps, t0_s, trigger + t0_s if plausible else None,
                                   int(cfh.ImageCount), h, w, self.effective_bits)
        self._check_size()

    def _check_size(self) -> None:
        size = self.path.stat().st_size
        for k, offset in enumerate(self._hdr["pImage"]):
            if offset < 0 or offset + 8 + self.frame_bytes > size:
                raise FrameError(
                    f"{self.path}: truncated or corrupt: frame {k} of {self.header.n_frames} would end at byte "
                    f"{offset + 8 + self.frame_bytes} but the file holds {size} bytes")

    def read(self, k: int) -> np.ndarray:
        """Frame ``k`` (0-based, file order) as a top-down image; FrameError naming file and frame."""
        where = f"{self.path} frame {k}"
        try:
            if self.bits == 8:
                return self._read_8bit(k)
            from pycine.raw import frame_reader

            image = next(frame_reader(str(self.path), self._hdr, start_frame=k + 1, count=1))
        except (OSError, ValueError, struct.error, StopIteration) as exc:
            raise FrameError(f"{where}: cannot decode ({type(exc).__name__}: {exc})") from None
        return _shifted(np.ascontiguousarray(image, dtype=np.uint16), self.effective_bits, where)

    def _read_8bit(self, k: int) -> np.ndarray:
        h, w = self.header.height_px, self.header.width_px
        with self.path.open("rb") as f:
            f.seek(self._hdr["pImage"][k])
            (annotation_size,) = struct.unpack("<I", f.read(4))
            if annotation_size < 8:
                raise ValueError(f"annotation size {annotation_size} < 8")
            f.seek(annotation_size - 8, 1)
            (image_size,) = struct.unpack("<I", f.read(4))
            data = f.read(w * h)
        if image_size < w * h or len(data) < w * h:
            raise ValueError(f"image holds {min(image_size, len(data))} bytes, {w}x{h} px need {w * h}")
        return np.flipud(np.frombuffer(data, dtype=np.uint8).reshape(h, w)).copy()


def open_camera_file(path: str | Path) -> MrawFile | CineFile:
    """The reader for a .cih/.cihx (MRAW) or .cine file; FrameError naming the file if unreadable."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in MRAW_HEADER_SUFFIXES:
        return MrawFile(path)
    if suffix in CINE_SUFFIXES:
        return CineFile(path)
    raise FrameError(f"{path}: not a camera file ({', '.join(CAMERA_FILE_SUFFIXES)})")


def merge_camera_header(data: Any, header: CameraHeader, rig_src: str) -> Any:
    """rig.yaml's mapping with the camera keys the header gives filled in where rig.yaml leaves them out.

    ``camera.fps`` given in both and differing (relatively) by more than FPS_RELATIVE_TOLERANCE:
    refused (RigError): every time, velocity and the accelerometer alignment scale with it, so a
    wrong rate gives wrong numbers silently. ``camera.t0_s`` / ``camera.start_time_unix_s`` given in
    both and differing: rig.yaml's value is kept with a warning (they only set the time origin,
    which a lab may deliberately put on its DAQ's clock; CORs do not depend on it).
    """
    if not isinstance(data, Mapping) or not isinstance(data.get("camera"), Mapping):
        return data  # parse_rig reports it
    cam = dict(data["camera"])
    name = header.path.name

    def number(value: Any) -> bool:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)

    if cam.get("fps") is None:
        cam["fps"] = header.fps
        log.info("%s: camera.fps %g taken from %s", rig_src, header.fps, name)
    elif number(cam["fps"]) and abs(cam["fps"] - header.fps) > FPS_RELATIVE_TOLERANCE * header.fps:
        raise RigError(f"{rig_src}: key 'camera.fps' is {cam['fps']:g} but {name}'s header records {header.fps:g} "
                       "frames/s: every time and velocity would be off by their ratio; fix camera.fps or remove it "
                       "to use the camera's")
    if header.t0_s is not None:
        if cam.get("t0_s") is None:
            cam["t0_s"] = header.t0_s
        elif number(cam["t0_s"]) and abs(cam["t0_s"] - header.t0_s) > 0.5 / header.fps:
            log.warning("%s: key 'camera.t0_s' is %g s but %s's header puts frame 0 at %g s from the trigger; "
                        "rig.yaml's value is used", rig_src, cam["t0_s"], name, header.t0_s)
    if header.start_time_unix_s is not None:
        if cam.get("start_time_unix_s") is None:
            cam["start_time_unix_s"] = header.start_time_unix_s
        elif number(cam["start_time_unix_s"]) and \
                abs(cam["start_time_unix_s"] - header.start_time_unix_s) > START_TIME_TOLERANCE_S:
            log.warning("%s: key 'camera.start_time_unix_s' is %.6f but %s's header says %.6f (trigger time + "
                        "first image); rig.yaml's value is used", rig_src, cam["start_time_unix_s"], name,
                        header.start_time_unix_s)
    out = dict(data)
    out["camera"] = cam
    return out
