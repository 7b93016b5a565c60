"""Stream a recording's frames from ``frames/`` (PNG/TIFF), a video, or a camera file, one at a time.

Camera files (:mod:`.camera_files`): ``video.cihx``/``video.cih`` with ``video.mraw`` (Photron),
``video.cine`` (Phantom); their frames are numbered 0.. in file order.

Frames are never all held in memory. Frame k is at ``t0_s + k / fps``, k being the
frame number in the file name (:mod:`.frame_names`). A frame file that is missing
from the numbered sequence (a dropped frame), fails to decode, or differs in size or
pixel type from the first frame is yielded as a :class:`Frame` with ``image=None`` and
an ``error`` naming it, so that the gap stays visible downstream.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from vibro_model.errors import FrameError

from .camera_files import CAMERA_FILE_SUFFIXES, open_camera_file
from .frame_names import NAMING_RULE, frame_numbers
from .frames_source import VIDEO_SUFFIXES, find_frames_source  # noqa: F401  (re-exported)
from .paths import inside_recording
from .rig import CameraConfig

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


@dataclass
class Frame:
    """One frame: index k, time t_s (s), grayscale image (uint8/uint16) or None with an error."""

    index: int
    t_s: float
    image: np.ndarray | None
    source: str
    error: str | None = None
    dropped: bool = False  # True: no file for this frame number (the camera dropped it)

    @property
    def ok(self) -> bool:
        return self.image is not None


def _to_gray(image: np.ndarray, source: str) -> np.ndarray:
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    if image.ndim != 2:
        raise FrameError(f"{source}: expected a grayscale image, got shape {image.shape}")
    if image.dtype not in (np.uint8, np.uint16):
        raise FrameError(f"{source}: expected 8- or 16-bit pixels, got {image.dtype}")
    return image


def read_image(path: str | Path) -> np.ndarray:
    """Read one 8/16-bit grayscale image file; raises :class:`FrameError` naming it."""
    path = Path(path)
    if not path.is_file():
        raise FrameError(f"{path}: frame file not found")
    data = np.fromfile(str(path), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise FrameError(f"{path}: cannot decode image (corrupt or not PNG/TIFF)")
    return _to_gray(image, str(path))


MAX_UNREADABLE_FRACTION = 0.05  # more unreadable frames than this (and more than one) refuse the recording


class FrameSequence:
    """Frames of a recording, read lazily from an image folder or a video file.

    In a folder, each file's frame number comes from its name (:mod:`.frame_names`);
    frame k is at ``t0_s + k / fps``. ``first_index`` is the lowest number present (0
    unless frame 0 is missing) and ``len()`` the number of frame slots from there to the
    last frame, dropped ones included. ``shape`` and ``dtype`` are those of the first
    frame; a frame of another size or pixel type is yielded as unreadable (``ok`` False,
    ``error`` naming file, size and expected size), like a frame that fails to decode.
    When more than :data:`MAX_UNREADABLE_FRACTION` of the slots (and more than one frame)
    turn out unreadable, iteration raises :class:`FrameError`: the recording is refused.
    ``root``, when given, is the recording directory every frame file must resolve inside.
    """

    def __init__(self, source: str | Path, camera: CameraConfig, root: str | Path | None = None):
        self.source = Path(source)
        self.camera = camera
        self.first_index = 0
        self._camera_file = None  # a Photron MRAW / Phantom CINE reader (camera_files), else None
        if self.source.is_dir():
            self._files = self._list_files(self.source, root)
            self._slots = self._number_slots(self._files)
            self._count = len(self._slots)
            first = read_image(self._slots[0])
        elif self.source.is_file() and self.source.suffix.lower() in CAMERA_FILE_SUFFIXES:
            self._files, self._slots = [], []
            self._camera_file = open_camera_file(self.source)
            self._camera_slots = self._slots_of(self._camera_file.header.time_base.slots, len(self._camera_file))
            self._count = len(self._camera_slots)
            first = self._camera_file.read(next(i for i in self._camera_slots if i is not None))
        elif self.source.is_file():
            self._files, self._slots = [], []
            cap = self._open_video()
            ok, image = cap.read()
            self._count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            cap.release()
            if not ok:
                raise FrameError(f"{self.source}: cannot decode the first video frame")
            first = _to_gray(image, f"{self.source} frame 0")
        else:
            raise FrameError(f"{self.source}: no such frames folder or video file")
        self.shape: tuple[int, int] = first.shape  # (rows, cols)
        self.dtype = first.dtype
        #: Significant bits per pixel: 8 for uint8; a camera file's effective depth (its pixels sit at the top
        #: of 16 bits, so the brightest code is 65535 - (2**(16 - effective_bits) - 1)); 16 for other 16-bit images.
        self.effective_bits: int = 8 if first.dtype == np.uint8 else (
            self._camera_file.effective_bits if self._camera_file is not None else 16)
        #: A video file's codec (FourCC, e.g. "FFV1", "H264", "mp4v"), "" for image folders and camera files.
        self.codec: str = self._video_codec() if not self._slots and self._camera_file is None else ""
        self.max_unreadable = max(1, int(MAX_UNREADABLE_FRACTION * self._count))

    def _slots_of(self, slots: np.ndarray | None, n_images: int) -> list[int | None]:
        """Image index of each frame slot of a camera file (None: a slot its clock leaves empty)."""
        if slots is None:
            return list(range(n_images))
        out: list[int | None] = [None] * (int(slots.max()) + 1)
        for image, slot in enumerate(slots):
            if slot >= 0:
                out[int(slot)] = image
        empty = [k for k, image in enumerate(out) if image is None]
        if empty:
            log.warning("%s: %d frame slot(s) empty by the images' time stamps (dropped frames), first at index %d",
                        self.source, len(empty), empty[0])
        return out

    @staticmethod
    def _list_files(folder: Path, root: str | Path | None) -> list[Path]:
        """The image files of ``folder``; with ``root``, each must resolve inside it: the folder is resolved
        once, and only the files that are symlinks each (a plain file of a folder inside lies inside; resolving
        all 20,000 of a long take cost 2 s)."""
        with os.scandir(folder) as entries:
            found = [e for e in entries if os.path.splitext(e.name)[1].lower() in IMAGE_SUFFIXES]
        if not found:
            raise FrameError(f"{folder}: no .png/.tif/.tiff frame files")
        files = [folder / e.name for e in found]
        if root is not None:
            inside_recording(root, folder.relative_to(root), f"frames folder {folder.name}")
            for entry, path in zip(found, files):
                if entry.is_symlink():
                    inside_recording(root, path.relative_to(root), f"frame file {path.name}")
        return files

    def _number_slots(self, files: list[Path]) -> list[Path | None]:
        """Place files by the frame number in their names; None marks a dropped frame."""
        numbers = frame_numbers(files)
        self.first_index = lo = min(numbers)
        n_slots = max(numbers) - lo + 1
        if n_slots > 2 * len(files):
            raise FrameError(
                f"{files[0].parent}: frame numbers run from {lo} to {max(numbers)} but only {len(files)} files "
                f"exist: more than half the frames would be dropped; the number that changes across the names "
                f"must count frames (not a time stamp or a step of more than 1); {NAMING_RULE}")
        slots: list[Path | None] = [None] * n_slots
        for n, path in zip(numbers, files):
            slots[n - lo] = path
        folder = files[0].parent
        if lo > 0:
            log.warning("%s: frame 0 is missing: the first frame file present, %s, is frame %d (at t0_s + %d/fps, "
                        "the time origin is kept); displacements are measured from frame %d, not frame 0",
                        folder, slots[0].name, lo, lo, lo)
        missing = [lo + i for i, p in enumerate(slots) if p is None]
        if missing:
            log.warning("%s: %d frame file(s) missing (dropped frames), first at index %d",
                        folder, len(missing), missing[0])
        return slots

    def _video_codec(self) -> str:
        cap = self._open_video()
        try:
            code = int(cap.get(cv2.CAP_PROP_FOURCC))
        finally:
            cap.release()
        return "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4)).strip("\x00 ")

    def _open_video(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(str(self.source))
        if not cap.isOpened():
            raise FrameError(f"{self.source}: OpenCV cannot open this video")
        return cap

    def __len__(self) -> int:
        return self._count

    @property
    def camera_file(self):
        """The Photron MRAW / Phantom CINE reader of a camera-file source (its ``header``), else None."""
        return self._camera_file

    def __getstate__(self) -> dict:
        """Pickled for another process (a Dask worker tracking a chunk): a camera file's reader is opened
        again there (by its path); the file list, sizes and numbering are carried over, not re-checked."""
        state = self.__dict__.copy()
        state["_camera_file"] = None
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if self.source.is_file() and self.source.suffix.lower() in CAMERA_FILE_SUFFIXES:
            self._camera_file = open_camera_file(self.source)

    def _mismatch(self, image: np.ndarray, where: str) -> str | None:
        """Why ``image`` does not match the first frame (size, pixel type), or None."""
        if image.shape != self.shape:
            return (f"{where}: frame size {image.shape[1]}x{image.shape[0]} px differs from the expected "
                    f"{self.shape[1]}x{self.shape[0]} px (the first frame's); frame treated as unreadable")
        if image.dtype != self.dtype:
            return (f"{where}: pixel type {image.dtype} differs from the expected {self.dtype} "
                    f"(the first frame's); frame treated as unreadable")
        return None

    def __iter__(self) -> Iterator[Frame]:
        guard = self.unreadable_guard()
        for frame in self.iter_slots():
            guard.check(frame)
            yield frame

    def unreadable_guard(self) -> "UnreadableGuard":
        """The check that refuses the recording once too many of its frames are unreadable (fed in order)."""
        return UnreadableGuard(self.source, self._count, self.max_unreadable)

    def iter_slots(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Frames of slot positions ``start`` .. ``stop`` - 1 (``stop`` None: to the end), WITHOUT the
        unreadable-fraction check (:meth:`unreadable_guard`, which ``iter()`` applies): a chunk of the
        recording for one worker, whose frames the caller feeds to the guard in order."""
        if self._camera_file is not None:
            return self._iter_camera_file(start, stop)
        return self._iter_files(start, stop) if self._slots else self._iter_video(start, stop)

    def _iter_files(self, start: int, stop: int | None) -> Iterator[Frame]:
        for pos, path in enumerate(self._slots[start:stop], start=start):
            k = self.first_index + pos
            t = self.camera.frame_time_s(k)
            if path is None:
                yield Frame(k, t, None, str(self.source), f"frame {k}: file missing (dropped frame)", dropped=True)
                continue
            try:
                image = read_image(path)
            except FrameError as exc:
                yield Frame(k, t, None, str(path), f"frame {k}: {exc}")
                continue
            problem = self._mismatch(image, f"frame {k}: {path}")
            yield Frame(k, t, None if problem else image, str(path), problem)

    def _iter_camera_file(self, start: int, stop: int | None) -> Iterator[Frame]:
        for k in range(start, self._count if stop is None else min(stop, self._count)):
            where = f"{self.source} frame {k}"
            t = self.camera.frame_time_s(k)
            image_index = self._camera_slots[k]
            if image_index is None:
                yield Frame(k, t, None, where, f"frame {k}: no image in this slot by the camera's time stamps "
                            "(dropped frame)", dropped=True)
                continue
            try:
                image = self._camera_file.read(image_index)
            except FrameError as exc:
                yield Frame(k, t, None, where, f"frame {k}: {exc}")
                continue
            problem = self._mismatch(image, where)
            yield Frame(k, t, None if problem else image, where, problem)

    def _iter_video(self, start: int, stop: int | None) -> Iterator[Frame]:
        cap = self._open_video()
        try:
            k = 0
            while k < start and cap.grab():  # frame-exact skip (seeking by position is not, in every codec)
                k += 1
            while stop is None or k < stop:
                ok, image = cap.read()
                if not ok:
                    break
                where = f"{self.source} frame {k}"
                t = self.camera.frame_time_s(k)
                try:
                    gray = _to_gray(image, where)
                except FrameError as exc:
                    yield Frame(k, t, None, where, str(exc))
                else:
                    problem = self._mismatch(gray, where)
                    yield Frame(k, t, None if problem else gray, where, problem)
                k += 1
            if k < self._count and (stop is None or stop > k):
                log.warning("%s: video ended after %d of %d announced frames", self.source, k, self._count)
        finally:
            cap.release()


class UnreadableGuard:
    """Counts the unreadable frames (not dropped ones) of one pass over a recording, in frame order, and
    raises :class:`FrameError` when more than ``max_unreadable`` of the ``count`` slots are unreadable."""

    def __init__(self, source: Path, count: int, max_unreadable: int):
        self.source, self.count, self.max_unreadable = source, count, max_unreadable
        self.unreadable: list[str] = []

    def check(self, frame: Frame) -> None:
        if not frame.ok and not frame.dropped:
            self.unreadable.append(frame.error or f"frame {frame.index}")
            if len(self.unreadable) > self.max_unreadable:
                raise FrameError(
                    f"{self.source}: {len(self.unreadable)} of {self.count} frames are unreadable (more than "
                    f"{MAX_UNREADABLE_FRACTION:.0%}); the recording is refused; first: {self.unreadable[0]}")
