"""Open a recording directory: validated rig, lazily read frames, optional accelerometers."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vibro_model.errors import RecordingError

from .accel import AccelData, load_accel
from .frames import FrameSequence, find_frames_source
from .paths import inside_recording
from .rig import RigConfig, check_rois_in_image, load_rig
from .tdms import load_tdms_accel


@dataclass
class Recording:
    """A recording on disk (see docs/recording-format.md)."""

    path: Path
    rig: RigConfig
    frames: FrameSequence

    @property
    def has_accel(self) -> bool:
        return self.rig.accelerometers is not None

    def load_accel(self) -> AccelData | None:
        """The accelerometer samples, or None for a video-only recording."""
        return load_recording_accel(self.path, self.rig)


def accel_file(recording: str | Path, rig: RigConfig) -> Path | None:
    """The accelerometer file rig.yaml names (None if none), checked to lie inside ``recording``."""
    cfg = rig.accelerometers
    if cfg is None:
        return None
    recording = Path(recording)
    path = inside_recording(recording, cfg.file, f"{recording / 'rig.yaml'}: key 'accelerometers.file'")
    if not path.is_file():
        raise RecordingError(
            f"{recording / 'rig.yaml'}: key 'accelerometers.file' names {cfg.file}, which is not in {recording}")
    return path


def load_recording_accel(recording: str | Path, rig: RigConfig) -> AccelData | None:
    """The samples of the recording's accelerometer file (None for a video-only recording).

    The file must lie inside ``recording``; its sample rate is checked against the camera's fps.
    A ``.tdms`` file is read by :func:`vibro_io.tdms.load_tdms_accel` (DAQ's own time base), else CSV.
    """
    path = accel_file(recording, rig)
    if path is None:
        return None
    if rig.accelerometers.is_tdms:

        return load_tdms_accel(path, rig.accelerometers, rig.camera)
    return load_accel(path, rig.accelerometers, camera_fps=rig.camera.fps)


def open_recording(path: str | Path) -> Recording:
    """Validate rig.yaml and the frames (count, size, ROIs) before any work is done."""
    path = Path(path)
    if not path.is_dir():
        raise RecordingError(f"{path}: not a recording directory")
    rig = load_rig(path / "rig.yaml")
    frames = FrameSequence(find_frames_source(path), rig.camera, root=path)
    check_rois_in_image(rig, *frames.shape)
    accel_file(path, rig)
    return Recording(path=path, rig=rig, frames=frames)
