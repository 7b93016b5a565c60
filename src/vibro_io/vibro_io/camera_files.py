"""High-speed camera files: Photron MRAW (+ .cih/.cihx header) and Phantom CINE, one frame at a time.

Readers: pyMRAW (header parsing and checks, and its 12-bit unpacker applied to one frame at a
time) and pycine (CINE header structures and frame offsets; its 10-bit unpacker). Memory stays
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

from .camera_time import TimeBase, from_header_step, from_stamps

log = logging.getLogger(__name__)

MRAW_HEADER_SUFFIXES = (".cihx", ".cih")
CINE_SUFFIXES = (".cine",)
CAMERA_FILE_SUFFIXES = MRAW_HEADER_SUFFIXES + CINE_SUFFIXES

#: rig.yaml's camera.start_time_unix_s further than this from the header's draws a warning (s).
START_TIME_TOLERANCE_S = 1e-3


@dataclass(frozen=True)
class CameraHeader:
    """What a camera file says about its frames.

    ``time_base`` (:class:`~vibro_io.camera_time.TimeBase`): where the saved frames lie in time, from the
    file's own clock where it has one; ``fps`` is its rate of the saved frames (frames/s; None when the
    header contradicts itself), ``t0_s`` the time of frame slot 0 relative to the trigger (s, or None),
    ``start_time_unix_s`` its wall-clock time (Unix s, or None). ``n_frames``: images in the file;
    ``bits``: significant bits per pixel.
    """

    path: Path
    time_base: TimeBase
    start_time_unix_s: float | None
    n_frames: int
    height_px: int
    width_px: int
    bits: int

    @property
    def fps(self) -> float | None:
        return self.time_base.fps

    @property
    def t0_s(self) -> float | None:
        return self.time_base.t0_s


def _shifted(image: np.ndarray, effective_bits: int, where: str) -> np.ndarray:
    """``image`` (uint16 holding ``effective_bits`` low bits) moved to the top of 16 bits; FrameError if wider."""
    if effective_bits >= 16:
        return image
    if int(image.max(initial=0)) >> effective_bits:
        raise FrameError(f"{where}: pixel value {int(image.max())} exceeds the header's {effective_bits}-bit depth")
    return image << np.uint16(16 - effective_bits)


def _sibling(path: Path, suffix: str) -> Path:
    """``path`` with ``suffix``, in whatever case the file on disk has it (video.CIHX + video.MRAW)."""
    for candidate in (path.with_suffix(suffix), path.with_suffix(suffix.upper())):
        if candidate.is_file():
            return candidate
    matches = [p for p in path.parent.glob(path.stem + ".*") if p.suffix.lower() == suffix]
    return matches[0] if matches else path.with_suffix(suffix)


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
        self.path = _sibling(self.header_path, ".mraw")
        cih = self._read_cih(pyMRAW)
        n, h, w = cih["Total Frame"], cih["Image Height"], cih["Image Width"]
        self.bits = cih["Color Bit"]
        self.effective_bits = 8 if self.bits == 8 else min(int(cih["EffectiveBit Depth"]), 16)
        self.higher = str(cih["EffectiveBit Side"]).lower() == "higher"
        if self.bits == 12 and (h * w) % 2:
            raise FrameError(f"{self.header_path}: a 12-bit MRAW needs an even pixel count per frame, got {w}x{h}")
        self.frame_bytes = h * w * self.bits // 8
        fps = float(cih["Record Rate(fps)"])
        frame_info = self._cihx_frame_info()
        start = cih.get("Start Frame", frame_info.get("startFrame"))
        step = cih.get("Save Step", frame_info.get("skipFrame", 1))
        recorded = cih.get("Original Total Frame", frame_info.get("recordedFrame"))
        if isinstance(step, bool) or not isinstance(step, int) or step < 1:
            raise FrameError(f"{self.header_path}: header saved-frame step (Save Step / skipFrame) must be a "
                             f"positive integer, got {step!r}")
        base = from_header_step(fps, step, n, recorded if isinstance(recorded, int) else None,
                                start if isinstance(start, int) else None, self.header_path.name)
        self.header = CameraHeader(self.header_path, base, None, n, h, w, self.effective_bits)
        self._check_size()

    def _read_cih(self, pyMRAW: Any) -> dict:
        if not self.path.is_file():
            raise FrameError(f"{self.header_path}: its image file {self.path.name} is missing")
        try:
            cih = self._parse_header(pyMRAW)
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

    def _parse_header(self, pyMRAW: Any) -> dict:
        """The header dict pyMRAW reads; a header whose extension is not lower case (video.CIHX) is parsed from a copy
        named in lower case (pyMRAW dispatches on the exact extension)."""
        suffix = self.header_path.suffix
        if suffix == suffix.lower():
            return pyMRAW.get_cih(str(self.header_path))
        import shutil
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            copy = Path(tmp) / ("header" + suffix.lower())
            shutil.copyfile(self.header_path, copy)
            return pyMRAW.get_cih(str(copy))

    def _cihx_frame_info(self) -> dict[str, int]:
        """The integers under frameInfo of a .cihx (startFrame, skipFrame, recordedFrame, ...: pyMRAW's dict
        leaves them out); empty for a .cih or an unreadable block."""
        if self.header_path.suffix.lower() != ".cihx":
            return {}
        import xml.etree.ElementTree as ET

        text = self.header_path.read_text(encoding="utf-8", errors="ignore")
        start, end = text.find("<cih>"), text.rfind("</cih>")
        try:
            info = ET.fromstring(text[start:end + 6]).find("frameInfo")
        except ET.ParseError:
            return {}
        out = {}
        for child in [] if info is None else list(info):
            try:
                out[child.tag] = int((child.text or "").strip())
            except ValueError:
                continue
        return out

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


def _plausible_wall_time(unix_s: float) -> bool:
    """A camera clock reading (Unix s) that can be a date: from 2000-01-01 to a day after now."""
    return 946684800.0 <= unix_s <= time.time() + 86400.0


#: CINE biCompression codes: uncompressed, packed 10-bit (pycine decodes it), packed 12-bit.
CINE_UNCOMPRESSED, CINE_PACKED_10BIT, CINE_PACKED_12BIT = 0, 256, 1024
#: CINE tagged-block types holding one TIME64 per image: "time only" (1002) and its older form (1001).
CINE_TIME_BLOCKS = (1002, 1001)


class CineFile(_CameraFile):
    """A Phantom CINE file: pycine reads the header and the frame offsets; frames are decoded here.

    Uncompressed frames (8 or 16 bits per pixel) are read as the camera wrote them: at the frame's
    offset a 32-bit annotation size (annotation skipped), a 32-bit image size, then the rows
    bottom-up (flipped to top-down). The raw values are delivered (MSB-aligned to 16 bits for
    ``RealBPP`` < 16): pycine's rescaling from the setup's BlackLevel/WhiteLevel is a display
    mapping, and an old file with meaningless levels decodes through it to all-zero frames. Packed
    10-bit frames (compression 256) go through pycine's unpacker and its 10-to-12-bit linearising
    table (delivered as 12-bit). Colour files (a colour filter array or RGB pixels) are refused by name.
    Each frame is checked after decoding: values beyond the declared depth, or a constant frame whose
    raw bytes vary, raise :class:`FrameError` naming the cause.

    The time base is the images' own time stamps (tagged block 1002) where the file has them
    (:mod:`.camera_time`), else the setup's frame rate and ``FirstImageNo``.
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
        self._check_pixel_format(int(bih.biBitCount), int(bih.biCompression), int(setup.CFA))
        self.compression = int(bih.biCompression)
        self.bits = 8 if bih.biBitCount == 8 else 16
        packed = self.compression == CINE_PACKED_10BIT
        self.effective_bits = 8 if self.bits == 8 else (12 if packed else int(setup.RealBPP))
        if not 8 <= self.effective_bits <= 16:
            raise FrameError(f"{self.path}: header RealBPP {setup.RealBPP} is not between 8 and 16 bits")
        fps = float(setup.FrameRate or setup.FrameRate16)
        if not fps > 0:
            raise FrameError(f"{self.path}: header frame rate (setup.FrameRate) is 0")
        trigger = cfh.TriggerTime.seconds + cfh.TriggerTime.fractions / 2.0 ** 32
        plausible = _plausible_wall_time(trigger)
        self.frame_bytes = (w * h * 10 // 8) if packed else w * h * self.bits // 8
        n = int(cfh.ImageCount)
        base = self._time_base(n, fps, (int(cfh.TriggerTime.seconds), int(cfh.TriggerTime.fractions))
                               if plausible else None)
        start = base.start_unix_s if base.source == "time stamps" else (
            trigger + base.t0_s if plausible and base.t0_s is not None else None)
        if start is not None and not _plausible_wall_time(start):
            start = None
        self.header = CameraHeader(self.path, base, start, n, h, w, self.effective_bits)
        self._check_size()

    def _check_pixel_format(self, bit_count: int, compression: int, cfa: int) -> None:
        if bit_count in (24, 48) or (cfa & 0xFF) != 0:
            what = f"{bit_count}-bit RGB pixels" if bit_count in (24, 48) else f"a colour filter array (CFA code {cfa})"
            raise FrameError(f"{self.path}: a colour CINE ({what}): vibro tracks grayscale frames; save the cine "
                             "as grayscale (Phantom PCC: File > Save As, or a monochrome camera) and try again")
        if bit_count not in (8, 16) or compression not in (CINE_UNCOMPRESSED, CINE_PACKED_10BIT):
            kind = {CINE_PACKED_12BIT: "packed 12-bit"}.get(compression, f"compression code {compression}")
            raise FrameError(f"{self.path}: {bit_count}-bit frames with {kind} are not supported (grayscale "
                             "uncompressed 8/16-bit and packed 10-bit CINE are)")

    def _time_stamps(self, n: int) -> np.ndarray | None:
        """The images' TIME64 stamps from the tagged blocks after the setup, as (seconds, fractions of 2**-32 s)
        integer pairs (n, 2); None without them."""
        cfh, setup = self._hdr["cinefileheader"], self._hdr["setup"]
        if int(setup.Length) < 8:
            return None  # a writer that leaves the setup's length out: no way to find the tagged blocks
        start, end = int(cfh.OffSetup) + int(setup.Length), int(cfh.OffImageOffsets)
        with self.path.open("rb") as f:
            f.seek(start)
            blocks = f.read(max(0, end - start))
        offset = 0
        while offset + 8 <= len(blocks):
            size, kind, _ = struct.unpack_from("<IHH", blocks, offset)
            if size < 8:
                break
            if kind in CINE_TIME_BLOCKS and size >= 8 + 8 * n and offset + 8 + 8 * n <= len(blocks):
                pairs = np.frombuffer(blocks, dtype="<u4", count=2 * n, offset=offset + 8).reshape(n, 2)
                return np.stack([pairs[:, 1], pairs[:, 0]], axis=1).astype(np.int64)
            offset += size
        return None

    def _time_base(self, n: int, fps: float, trigger: tuple[int, int] | None) -> TimeBase:
        """From the stamps where the file has them (seconds counted from the trigger's whole second, in
        integers first: a Unix time in float64 resolves only 0.24 us), else the header."""
        stamps = self._time_stamps(n) if n >= 2 else None
        if stamps is not None:
            origin = trigger[0] if trigger is not None else int(stamps[:, 0].min())
            rel = (stamps[:, 0] - origin).astype(np.float64) + stamps[:, 1] / 2.0 ** 32
            trigger_rel = None if trigger is None else trigger[1] / 2.0 ** 32
            try:
                return from_stamps(rel, float(origin), fps, trigger_rel, self.path.name)
            except ValueError as exc:
                raise FrameError(f"{self.path}: the images' time stamps (tagged block 1002) are not a clock: "
                                 f"{exc}") from None
        first = int(self._hdr["cinefileheader"].FirstImageNo)
        return TimeBase(fps=fps, source="header", record_fps=fps, t0_s=first / fps)

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
            raw = self._raw_bytes(k)
        except (OSError, ValueError, struct.error) as exc:
            raise FrameError(f"{where}: cannot decode ({type(exc).__name__}: {exc})") from None
        h, w = self.header.height_px, self.header.width_px
        if self.bits == 8:
            values = image = np.flipud(np.frombuffer(raw, dtype=np.uint8).reshape(h, w)).copy()
        elif self.compression == CINE_PACKED_10BIT:
            from pycine.linLUT import linLUT
            from pycine.raw import unpack_10bit

            values = unpack_10bit(raw, w, h)  # rows as pycine orders them
            image = np.asarray(linLUT, dtype=np.uint16)[values]
        else:
            values = image = np.flipud(np.frombuffer(raw, dtype="<u2").reshape(h, w)).astype(np.uint16)
        if image.size > 1 and image.min() == image.max() and values.min() != values.max():
            raise FrameError(f"{where}: decodes to a constant frame ({int(image.min())}) although its raw values span "
                             f"{int(values.min())}..{int(values.max())}: the decoder does not understand this file")
        return image if self.bits == 8 else _shifted(np.ascontiguousarray(image), self.effective_bits, where)

    def _raw_bytes(self, k: int) -> bytes:
        """The image bytes of frame ``k``: past its annotation block, as many as the frame holds."""
        with self.path.open("rb") as f:
            f.seek(self._hdr["pImage"][k])
            (annotation_size,) = struct.unpack("<I", f.read(4))
            if annotation_size < 8:
                raise ValueError(f"annotation size {annotation_size} < 8")
            f.seek(annotation_size - 8, 1)
            (image_size,) = struct.unpack("<I", f.read(4))
            data = f.read(self.frame_bytes)
        if image_size < self.frame_bytes or len(data) < self.frame_bytes:
            raise ValueError(f"image holds {min(image_size, len(data))} bytes, {self.header.width_px}x"
                             f"{self.header.height_px} px need {self.frame_bytes}")
        return data


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

    ``camera.fps`` is the spacing of the *saved* frames (:attr:`CameraHeader.fps`, from the file's
    own time stamps, or the header's rate and saved-frame step). Given in rig.yaml, it must name the
    same spacing (within :func:`~vibro_io.camera_time.fps_tolerance`), else it is refused
    (RigError naming both): every time, velocity and the accelerometer alignment scale with it.
    Where the header contradicts itself (``fps`` None) rig.yaml must give camera.fps, one of the
    header's readings. ``camera.t0_s`` / ``camera.start_time_unix_s`` given in both and differing:
    rig.yaml's value is kept with a warning (they only set the time origin, which a lab may
    deliberately put on its DAQ's clock; CORs do not depend on it).
    """
    if not isinstance(data, Mapping) or not isinstance(data.get("camera"), Mapping):
        return data  # parse_rig reports it
    cam = dict(data["camera"])
    if header.time_base.fps is not None:  # a contradictory header's note goes into the refusal or is settled
        for note in header.time_base.notes:  # by rig.yaml
            log.warning("%s", note)
    _merge_fps(cam, header, rig_src)
    _merge_time_origin(cam, header, rig_src)
    out = dict(data)
    out["camera"] = cam
    return out


def _is_number(value: Any) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _merge_fps(cam: dict, header: CameraHeader, rig_src: str) -> None:
    """Fill in ``cam["fps"]`` (frames/s) from the header's saved-frame spacing, or check rig.yaml's against it."""
    name = header.path.name
    base = header.time_base
    if base.fps is None:
        options = " or ".join(f"{c:g}" for c in base.candidates_fps)
        if cam.get("fps") is None:
            why = base.notes[0] if base.notes else f"{name}'s header allows {options} frames/s"
            raise RigError(f"{rig_src}: key 'camera.fps' is needed: {why}")
        if _is_number(cam["fps"]) and not base.names_same_spacing(cam["fps"], header.n_frames):
            raise RigError(f"{rig_src}: key 'camera.fps' is {cam['fps']:g} but {name}'s header allows {options} "
                           "frames/s only")
    elif cam.get("fps") is None:
        cam["fps"] = base.fps
        log.info("%s: camera.fps %.8g taken from %s (%s)", rig_src, base.fps, name, base.source)
    elif _is_number(cam["fps"]) and not base.names_same_spacing(cam["fps"], header.n_frames):
        header_said = (f"; its header says {base.record_fps:g} frames/s" if base.source != "header" else "")
        raise RigError(f"{rig_src}: key 'camera.fps' is {cam['fps']:g} but {name}'s saved frames are "
                       f"{1.0 / base.fps:.6g} s apart ({base.fps:.8g} frames/s, from its {base.source}"
                       f"{header_said}): every time and velocity would be off by their ratio "
                       f"{cam['fps'] / base.fps:.4g}; fix camera.fps or remove it to use the file's")


def _merge_time_origin(cam: dict, header: CameraHeader, rig_src: str) -> None:
    """Fill in ``cam``'s t0_s (s) and start_time_unix_s (Unix s) from the header; where rig.yaml gives a
    different one, keep it with a warning."""
    name = header.path.name
    if header.t0_s is not None:
        if cam.get("t0_s") is None:
            cam["t0_s"] = header.t0_s
        elif (_is_number(cam["t0_s"]) and _is_number(cam.get("fps"))
              and abs(cam["t0_s"] - header.t0_s) > 0.5 / cam["fps"]):
            log.warning("%s: key 'camera.t0_s' is %g s but %s's header puts frame 0 at %g s from the trigger; "
                        "rig.yaml's value is used", rig_src, cam["t0_s"], name, header.t0_s)
    if header.start_time_unix_s is not None:
        if cam.get("start_time_unix_s") is None:
            cam["start_time_unix_s"] = header.start_time_unix_s
        elif _is_number(cam["start_time_unix_s"]) and \
                abs(cam["start_time_unix_s"] - header.start_time_unix_s) > START_TIME_TOLERANCE_S:
            log.warning("%s: key 'camera.start_time_unix_s' is %.6f but %s's header says %.6f (trigger time + "
                        "first image); rig.yaml's value is used", rig_src, cam["start_time_unix_s"], name,
                        header.start_time_unix_s)
