"""Read ``accel.csv``: accelerometer samples of the upper and lower plates (m/s^2)."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import AccelError
from .rig import AccelConfig


@dataclass
class AccelData:
    """Samples on one clock: t_s (s, increasing), upper_ms2 and lower_ms2 (m/s^2)."""

    t_s: np.ndarray
    upper_ms2: np.ndarray
    lower_ms2: np.ndarray

    @property
    def sample_rate_hz(self) -> float:
        """Median sample rate (Hz)."""
        return float(1.0 / np.median(np.diff(self.t_s)))

    def __len__(self) -> int:
        return int(self.t_s.size)


def load_accel(path: str | Path, columns: AccelConfig) -> AccelData:
    """Read an accelerometer CSV; refuses non-numeric or non-increasing times naming the line."""
    path = Path(path)
    try:
        handle = path.open(newline="", encoding="utf-8")
    except OSError as exc:
        raise AccelError(f"{path}: cannot open accelerometer file ({exc})") from None
    with handle:
        reader = csv.reader(handle)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise AccelError(f"{path}: empty file, expected a header line") from None
        wanted = (columns.time_column, columns.upper_column, columns.lower_column)
        idx = []
        for name in wanted:
            if name not in header:
                raise AccelError(f"{path}: line 1: column '{name}' not found (header: {', '.join(header)})")
            idx.append(header.index(name))
        rows: list[tuple[float, float, float]] = []
        last_t = -math.inf
        for line_no, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            try:
                values = tuple(float(row[i]) for i in idx)
            except (ValueError, IndexError):
                raise AccelError(f"{path}: line {line_no}: non-numeric or missing value in {row!r}") from None
            if not all(math.isfinite(v) for v in values):
                raise AccelError(f"{path}: line {line_no}: non-finite value in {row!r}")
            if values[0] <= last_t:
                raise AccelError(
                    f"{path}: line {line_no}: time {values[0]} s does not increase (previous {last_t} s)"
                )
            last_t = values[0]
            rows.append(values)  # type: ignore[arg-type]
    if len(rows) < 2:
        raise AccelError(f"{path}: fewer than 2 samples")
    data = np.asarray(rows, dtype=float)
    return AccelData(t_s=data[:, 0], upper_ms2=data[:, 1], lower_ms2=data[:, 2])


def write_accel(path: str | Path, data: AccelData, columns: AccelConfig) -> None:
    """Write samples as CSV with the column names of ``columns``."""
    table = np.column_stack([data.t_s, data.upper_ms2, data.lower_ms2])
    header = f"{columns.time_column},{columns.upper_column},{columns.lower_column}"
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt=["%.7f", "%.6g", "%.6g"])
