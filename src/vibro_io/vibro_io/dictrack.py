"""The DIC track of a recording: per-frame displacements, as in ``dic.csv``.

Displacements are in mm since frame 0, positive up (towards the upper plate).
``ball_rot_rad`` is the ball mesh's in-plane rigid rotation since frame 0 (rad, positive
counter-clockwise as the camera sees the image), ``ball_rot_std_rad`` its 1-sigma noise from the
subsets' residuals about the rigid fit; both NaN when lost or unknown. A ``dic.csv`` written before
these two columns existed is read with them NaN.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Iterable

import numpy as np

from vibro_model.errors import RecordingError

DIC_COLUMNS = (
    "frame", "t_s", "ball_mm", "structure_mm", "ball_valid", "structure_valid",
    "ball_zncc", "structure_zncc", "lost", "ball_rot_rad", "ball_rot_std_rad",
)
#: the columns of a dic.csv written before the ball rotation existed (still read)
LEGACY_DIC_COLUMNS = DIC_COLUMNS[:9]


@dataclass(kw_only=True)
class FrameTrack:
    """DIC result of one frame. ``*_valid`` count mesh points kept; ``lost`` flags an unusable frame."""

    frame: int
    t_s: float
    ball_mm: float
    structure_mm: float
    ball_valid: int
    structure_valid: int
    ball_zncc: float
    structure_zncc: float
    lost: bool
    ball_rot_rad: float = math.nan       # in-plane rotation since frame 0 (rad, + counter-clockwise on screen)
    ball_rot_std_rad: float = math.nan   # its 1-sigma noise (rad)


@dataclass(kw_only=True)
class DicTrack:
    """Column arrays of a whole track (one entry per frame slot, lost frames included, NaN there)."""

    frame: np.ndarray
    t_s: np.ndarray
    ball_mm: np.ndarray
    structure_mm: np.ndarray
    ball_valid: np.ndarray
    structure_valid: np.ndarray
    ball_zncc: np.ndarray
    structure_zncc: np.ndarray
    lost: np.ndarray
    ball_rot_rad: np.ndarray | None = None       # None: not measured (NaN filled)
    ball_rot_std_rad: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.shape(self.frame)[0] if np.ndim(self.frame) else 0
        for name in ("ball_rot_rad", "ball_rot_std_rad"):
            value = getattr(self, name)
            setattr(self, name, np.full(n, np.nan) if value is None else np.asarray(value, dtype=float))

    @classmethod
    def from_frames(cls, rows: Iterable[FrameTrack]) -> "DicTrack":
        rows = list(rows)
        cols = {f.name: np.array([getattr(r, f.name) for r in rows]) for f in fields(FrameTrack)}
        cols["frame"] = cols["frame"].astype(int)
        cols["lost"] = cols["lost"].astype(bool)
        for name in ("t_s", "ball_mm", "structure_mm", "ball_zncc", "structure_zncc", "ball_rot_rad",
                     "ball_rot_std_rad"):
            cols[name] = cols[name].astype(float)
        return cls(**cols)

    def __len__(self) -> int:
        return int(self.frame.size)

    @property
    def good(self) -> np.ndarray:
        """Boolean mask of frames that are not lost and have finite displacements."""
        return ~self.lost & np.isfinite(self.ball_mm) & np.isfinite(self.structure_mm)


def write_dic_csv(path: str | Path, rows: Iterable[FrameTrack]) -> int:
    """Write rows to ``dic.csv`` (contract column order); returns the number written."""
    n = 0
    with Path(path).open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(DIC_COLUMNS)
        for r in rows:
            writer.writerow([
                r.frame, f"{r.t_s:.9f}", f"{r.ball_mm:.9g}", f"{r.structure_mm:.9g}",
                r.ball_valid, r.structure_valid, f"{r.ball_zncc:.6f}", f"{r.structure_zncc:.6f}", int(r.lost),
                f"{r.ball_rot_rad:.6e}", f"{r.ball_rot_std_rad:.3e}",
            ])
            n += 1
    return n


def read_dic_csv(path: str | Path) -> DicTrack:
    """Read a ``dic.csv`` (with or without the ball rotation columns); raises :class:`RecordingError`
    naming the line of a bad row."""
    path = Path(path)
    rows = []
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.reader(handle)
            header = next(reader, None)
            names = None if header is None else tuple(h.strip() for h in header)
            if names not in (DIC_COLUMNS, LEGACY_DIC_COLUMNS):
                raise RecordingError(f"{path}: line 1: expected columns {','.join(DIC_COLUMNS)} (or the first "
                                     f"{len(LEGACY_DIC_COLUMNS)} of them, as written before the ball rotation)")
            width = len(names)
            for line_no, row in enumerate(reader, start=2):
                try:
                    if len(row) != width:
                        raise ValueError
                    rot = (float(row[9]), float(row[10])) if width == len(DIC_COLUMNS) else (math.nan, math.nan)
                    rows.append(FrameTrack(
                        frame=int(row[0]), t_s=float(row[1]), ball_mm=float(row[2]), structure_mm=float(row[3]),
                        ball_valid=int(row[4]), structure_valid=int(row[5]), ball_zncc=float(row[6]),
                        structure_zncc=float(row[7]), lost=bool(int(row[8])), ball_rot_rad=rot[0],
                        ball_rot_std_rad=rot[1],
                    ))
                except (ValueError, IndexError):
                    raise RecordingError(f"{path}: line {line_no}: bad row {row!r}") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc})") from None
    return DicTrack.from_frames(rows)
