"""Stream a recording's frames from ``frames/`` (PNG/TIFF) or a video, one at a time.

Frames are never all held in memory. Frame k is at ``t0_s + k / fps``. A frame
file that is missing from a numbered sequence (a dropped frame) or fails to decode
is yielded as a :class:`Frame` with ``image=None`` and an ``error`` naming it, so
that the gap stays visible downstream.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from .errors import FrameError
from .rig import CameraConfig

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".tif", ".tiff")
VIDEO_SUFFIXES = (".avi", ".mp4", ".mov", ".mkv")


@dataclass
class Frame:
    """One frame: index k, time t_s (s), grayscale image (uint8/uint16) or None with an error."""

    index: int
    t_s: float
    image: np.ndarray | None
    source: str
    error: str | None = None

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


class FrameSequence:
    """Frames of a recording, read lazily from an image folder or a video file.

    ``len()`` is the number of frame slots (including dropped ones); ``shape`` and
    ``dtype`` are those of frame 0, which every other frame must match.
    """

    def __init__(self, source: str | Path, camera: CameraConfig):
        self.source = Path(source)
        self.camera = camera
        if self.source.is_dir():
            self._files = self._list_files(self.source)
            self._slots = self._number_slots(self._files)
            self._count = len(self._slots)
            first = read_image(self._files[0])
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

    @staticmethod
    def _list_files(folder: Path) -> list[Path]:
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise FrameError(f"{folder}: no .png/.tif/.tiff frame files")
        return files

    @staticmethod
    def _number_slots(files: list[Path]) -> list[Path | None]:
        """Place files by their number when all names are integers; None marks a dropped frame."""
        stems = [p.stem for p in files]
        if not all(s.isdigit() for s in stems):
            return list(files)
        numbers = [int(s) for s in stems]
        if len(set(numbers)) != len(numbers):
            raise FrameError(f"{files[0].parent}: two frame files share one frame number")
        first = numbers[0]
        slots: list[Path | None] = [None] * (numbers[-1] - first + 1)
        for n, path in zip(numbers, files):
            slots[n - first] = path
        missing = [i for i, p in enumerate(slots) if p is None]
        if missing:
            log.warning("%s: %d frame file(s) missing (dropped frames), first at index %d",
                        files[0].parent, len(missing), missing[0])
        return slots

    def _open_video(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(str(self.source))
        if not cap.isOpened():
            raise FrameError(f"{self.source}: OpenCV cannot open this video")
        return cap

    def __len__(self) -> int:
        return self._count

    def _check(self, image: np.ndarray, where: str) -> np.ndarray:
        if image.shape != self.shape:
            raise FrameError(
                f"{where}: frame size {image.shape[1]}x{image.shape[0]} differs from frame 0 "
                f"({self.shape[1]}x{self.shape[0]}); frames of differing size are refused"
            )
        if image.dtype != self.dtype:
            raise FrameError(f"{where}: pixel type {image.dtype} differs from frame 0 ({self.dtype})")
        return image

    def __iter__(self) -> Iterator[Frame]:
        if self._slots:
            yield from self._iter_files()
        else:
            yield from self._iter_video()

    def _iter_files(self) -> Iterator[Frame]:
        for k, path in enumerate(self._slots):
            t = self.camera.frame_time_s(k)
            if path is None:
                yield Frame(k, t, None, str(self.source), f"frame {k}: file missing (dropped frame)")
                continue
            try:
                image = read_image(path)
            except FrameError as exc:
                yield Frame(k, t, None, str(path), f"frame {k}: {exc}")
                continue
            yield Frame(k, t, self._check(image, f"{path} (frame {k})"), str(path))

    def _iter_video(self) -> Iterator[Frame]:
        cap = self._open_video()
        try:
            k = 0
            while True:
                ok, image = cap.read()
                if not ok:
                    break
                where = f"{self.source} frame {k}"
                yield Frame(k, self.camera.frame_time_s(k), self._check(_to_gray(image, where), where), where)
                k += 1
            if k < self._count:
                log.warning("%s: video ended after %d of %d announced frames", self.source, k, self._count)
        finally:
            cap.release()


def find_frames_source(recording: str | Path) -> Path:
    """The frames/ folder of a recording, else its video file; :class:`FrameError` if neither."""
    recording = Path(recording)
    if (recording / "frames").is_dir():
        return recording / "frames"
    videos = sorted(p for p in recording.glob("video.*") if p.suffix.lower() in VIDEO_SUFFIXES)
    if videos:
        return videos[0]
    raise FrameError(f"{recording}: no frames/ folder and no video.avi")
