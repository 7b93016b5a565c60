"""Where a recording's frames are: its frames/ folder, else its video or camera file (found by name).

Apart from :mod:`vibro_io.frames` (which reads them) so that rig.yaml's reader, which takes a camera file's
header for the keys it leaves out, can find the file without importing the frame reader (no import loop).
"""

from __future__ import annotations

import logging
from pathlib import Path

from vibro_model.errors import FrameError

from .camera_files import CAMERA_FILE_SUFFIXES
from .paths import inside_recording

log = logging.getLogger(__name__)

#: video containers read through OpenCV (``video.<suffix>``)
VIDEO_SUFFIXES = (".avi", ".mp4", ".mov", ".mkv")


def find_frames_source(recording: str | Path) -> Path:
    """The frames/ folder of a recording, else its video file; :class:`FrameError` if neither.

    The video is ``video.*`` (any case: ``video.CIHX`` + ``video.MRAW`` too); without one, a single
    camera file under its own name (``ball_12bit.cihx`` + ``ball_12bit.mraw``, ``take3.cine``) is used,
    and several are refused with one message saying what to rename. Either must resolve inside the
    recording directory (a symlink leading out is refused).
    """
    recording = Path(recording)
    if (recording / "frames").is_dir():
        return inside_recording(recording, "frames", "frames folder")
    files = sorted(p for p in recording.iterdir() if p.is_file()) if recording.is_dir() else []
    known = VIDEO_SUFFIXES + CAMERA_FILE_SUFFIXES
    videos = [p for p in files if p.stem.lower() == "video" and p.suffix.lower() in known]
    if any(p.suffix.lower() in CAMERA_FILE_SUFFIXES for p in videos) and len(videos) > 1:
        raise FrameError(f"{recording}: {len(videos)} video files ({', '.join(p.name for p in videos)}): "
                         "keep one (a Photron MRAW with one header, .cihx or .cih)")
    if videos:
        return inside_recording(recording, videos[0].name, "video file")
    cameras = [p for p in files if p.suffix.lower() in CAMERA_FILE_SUFFIXES]
    if len(cameras) == 1:
        log.info("%s: frames from the camera file %s", recording, cameras[0].name)
        return inside_recording(recording, cameras[0].name, "camera file")
    if cameras:
        raise FrameError(f"{recording}: {len(cameras)} camera files ({', '.join(p.name for p in cameras)}) and no "
                         "video.*: rename the one to analyse to video.<its extension> (a Photron header's .mraw to "
                         "video.mraw beside it) or move the others out")
    if any(p.stem.lower() == "video" and p.suffix.lower() == ".mraw" for p in files):
        raise FrameError(f"{recording}: video.mraw has no header beside it (video.cihx or video.cih)")
    raise FrameError(f"{recording}: no frames/ folder and no video.avi (nor another video.* of "
                     f"{', '.join(VIDEO_SUFFIXES)}, nor a camera file {', '.join(CAMERA_FILE_SUFFIXES)}: a Photron "
                     "header with its .mraw, a Phantom .cine)")
