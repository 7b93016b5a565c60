"""Open a recording directory: validated rig, lazily read frames, optional accelerometers."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .accel import AccelData, load_accel
from .errors import RecordingError
from .frames import FrameSequence, find_frames_source
from .rig import RigConfig, check_rois_in_image, load_rig


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
        cfg = self.rig.accelerometers
        if cfg is None:
            return None
        return load_accel(self.path / cfg.file, cfg)


def open_recording(path: str | Path) -> Recording:
    """Validate rig.yaml and the frames (count, size, ROIs) before any work is done."""
    path = Path(path)
    if not path.is_dir():
        raise RecordingError(f"{path}: not a recording directory")
    rig = load_rig(path / "rig.yaml")
    frames = FrameSequence(find_frames_source(path), rig.camera)
    check_rois_in_image(rig, *frames.shape)
    if rig.accelerometers is not None and not (path / rig.accelerometers.file).is_file():
        raise RecordingError(
            f"{path / 'rig.yaml'}: key 'accelerometers.file' names {rig.accelerometers.file}, "
            f"which is not in {path}"
        )
    return Recording(path=path, rig=rig, frames=frames)
