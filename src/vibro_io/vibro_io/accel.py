"""Read ``accel.csv``: accelerometer samples of the upper and lower plates, delivered in m/s^2.

The CSV's values are in rig.yaml's ``accelerometers.unit`` (m/s^2 when left out; g, V or mV
are converted, V and mV with ``accelerometers.sensitivity_mv_per_g``). :class:`AccelData`,
:func:`check_sample_rate` and :func:`warn_if_clipped` live in :mod:`vibro_io.accel_checks`
(shared with the TDMS reader) and are importable from here.
"""

from __future__ import annotations

import csv
import logging
import math
from pathlib import Path

import numpy as np

from vibro_model.errors import AccelError

from .accel_checks import (
    CLIP_RUN_SAMPLES,
    MAX_SAMPLE_RATE_HZ,
    MIN_SAMPLE_RATE_HZ,
    MS2,
    AccelData,
    check_sample_rate,
    mps2_per_unit,
    warn_if_clipped,
)
from .rig import AccelConfig
from .tdms import load_tdms_accel

__all__ = ["AccelData", "CLIP_RUN_SAMPLES", "MAX_SAMPLE_RATE_HZ", "MIN_SAMPLE_RATE_HZ", "check_sample_rate",
           "load_accel", "warn_if_clipped", "write_accel"]

log = logging.getLogger(__name__)


def _ends_with_newline(path: Path) -> bool:
    with path.open("rb") as handle:
        handle.seek(0, 2)
        if handle.tell() == 0:
            return True
        handle.seek(-1, 2)
        return handle.read(1) in (b"\n", b"\r")


def _parse_row(path: Path, line_no: int, row: list[str], idx: list[int], last_t: float
               ) -> tuple[float, float, float]:
    """(t_s, upper, lower) of one CSV row; :class:`AccelError` naming the line if bad or not after ``last_t``."""
    try:
        values = tuple(float(row[i]) for i in idx)
    except (ValueError, IndexError):
        raise AccelError(f"{path}: line {line_no}: non-numeric or missing value in {row!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise AccelError(f"{path}: line {line_no}: non-finite value in {row!r}")
    if values[0] <= last_t:
        raise AccelError(f"{path}: line {line_no}: time {values[0]} s does not increase (previous {last_t} s)")
    return values  # type: ignore[return-value]


def _whole_file_rows(path: Path, idx: list[int]) -> np.ndarray | None:
    """The time, upper and lower columns (``idx``) of every data row, parsed at once by numpy's C reader (a 4 s
    take at 50 kHz, 200,000 rows: 0.03 s against 0.55 s line by line) when the whole file is well formed:
    finite numbers and increasing times. None otherwise, and the line-by-line reader then names the first bad
    line."""
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=idx, comments=None, encoding="utf-8-sig",
                          dtype=float, ndmin=2)
    except (ValueError, IndexError, UnicodeDecodeError):
        return None
    if data.shape[0] < 2 or not np.all(np.isfinite(data)) or not np.all(np.diff(data[:, 0]) > 0):
        return None
    return data


def _rows_line_by_line(path: Path, reader, idx: list[int], complete_last_line: bool) -> np.ndarray:
    """The rows after the header from ``reader`` (a csv reader), each checked (:func:`_parse_row` names the
    line); blank rows skipped, a last line without a line end dropped with a warning."""
    rows: list[tuple[float, float, float]] = []
    pending: tuple[int, list[str]] | None = None  # held back: the last line may be cut short
    try:
        for line_no, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if pending is not None:
                rows.append(_parse_row(path, *pending, idx, rows[-1][0] if rows else -math.inf))
            pending = (line_no, row)
    except (UnicodeDecodeError, csv.Error) as exc:
        raise AccelError(f"{path}: line {reader.line_num}: not a UTF-8 CSV ({exc})") from None
    if pending is not None:
        if complete_last_line:
            rows.append(_parse_row(path, *pending, idx, rows[-1][0] if rows else -math.inf))
        else:
            log.warning("%s: line %d: last line has no line end (the writer stopped mid-line?); dropped, "
                        "%d complete rows kept", path, pending[0], len(rows))
    return np.asarray(rows, dtype=float).reshape(-1, 3)


def load_accel(path: str | Path, columns: AccelConfig, camera_fps: float | None = None) -> AccelData:
    """Read an accelerometer CSV.

    Parameters
    ----------
    path : str or Path
        The CSV file (a header row naming ``columns``' time, upper and lower columns).
    columns : AccelConfig
        rig.yaml's ``accelerometers`` block: column names, the samples' unit, the sensor sensitivity.
    camera_fps : float, optional
        The camera's frame rate (frames/s), which the sample rate must exceed.

    Returns
    -------
    AccelData
        Times (s, the file's time column) and both channels in m/s^2 (+ up).

    Raises
    ------
    AccelError
        Non-numeric or non-increasing times (naming the line), a missing column, an implausible rate.

    Notes
    -----
    A UTF-8 byte-order mark is accepted. A last line without a line end (the writer stopped
    mid-line) is dropped with a warning naming file and line. The sample rate implied by the
    time column (seconds) is checked: see :func:`check_sample_rate`.
    """
    path = Path(path)
    if columns.is_tdms:  # rig.yaml maps TDMS channels (vibro_io.tdms); without the camera's wall-clock start
        return load_tdms_accel(path, columns, camera_fps=camera_fps)
    try:
        handle = path.open(newline="", encoding="utf-8-sig")
        complete_last_line = _ends_with_newline(path)
    except OSError as exc:
        raise AccelError(f"{path}: cannot open accelerometer file ({exc})") from None
    with handle:
        reader = csv.reader(handle)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise AccelError(f"{path}: empty file, expected a header line") from None
        except (UnicodeDecodeError, csv.Error) as exc:
            raise AccelError(f"{path}: line 1: not a UTF-8 CSV header ({exc})") from None
        wanted = (columns.time_column, columns.upper_column, columns.lower_column)
        idx = []
        for name in wanted:
            if name not in header:
                shown = ", ".join(header)
                shown = shown if len(shown) <= 200 else shown[:200] + " ..."
                raise AccelError(f"{path}: line 1: column '{name}' not found (header: {shown})")
            idx.append(header.index(name))
        data = _whole_file_rows(path, idx) if complete_last_line else None
        if data is None:
            data = _rows_line_by_line(path, reader, idx, complete_last_line)
    if len(data) < 2:
        raise AccelError(f"{path}: fewer than 2 samples")
    check_sample_rate(float(1.0 / np.median(np.diff(data[:, 0]))), f"{path}: column '{columns.time_column}'",
                      camera_fps)
    for column, values in ((columns.upper_column, data[:, 1]), (columns.lower_column, data[:, 2])):
        warn_if_clipped(values, f"{path}: column '{column}'")
    scales = (csv_mps2_per_unit(columns, "upper", path), csv_mps2_per_unit(columns, "lower", path))
    unit = columns.unit or MS2
    return AccelData(t_s=data[:, 0], upper_ms2=data[:, 1] * scales[0], lower_ms2=data[:, 2] * scales[1],
                     source_units=(unit, unit), mps2_per_source_unit=scales,
                     unit_source="accelerometers.unit" if columns.unit else "default")


def csv_mps2_per_unit(columns: AccelConfig, role: str, path: Path | str) -> float:
    """The scale of a CSV column: m/s^2 per unit of its ``upper`` or ``lower`` column.

    Parameters
    ----------
    columns : AccelConfig
        rig.yaml's ``accelerometers`` block (``unit``: m/s^2 when None; ``sensitivity_mv_per_g`` for a voltage).
    role : str
        ``"upper"`` or ``"lower"``.
    path : str or Path
        The CSV, named in a refusal.

    Returns
    -------
    float
        m/s^2 per unit of the column.

    Notes
    -----
    A voltage unit without ``sensitivity_mv_per_g`` is refused (:class:`AccelError` naming the
    file and the rig.yaml key); rig.yaml's parser already refuses it, this guards a config built in code.
    """
    unit = columns.unit or MS2
    sensitivity = columns.sensitivity_mv_per_g.of(role) if columns.sensitivity_mv_per_g else None
    try:
        return mps2_per_unit(unit, sensitivity)
    except ValueError as exc:
        raise AccelError(f"{path}: accelerometers.unit {unit}: {exc} (accelerometers.sensitivity_mv_per_g "
                         "in rig.yaml)") from None


def write_accel(path: str | Path, data: AccelData, columns: AccelConfig) -> None:
    """Write samples as CSV with the column names of ``columns``, in its unit (m/s^2 when ``columns.unit`` is None)."""
    table = np.column_stack([data.t_s, data.upper_ms2 / csv_mps2_per_unit(columns, "upper", path),
                             data.lower_ms2 / csv_mps2_per_unit(columns, "lower", path)])
    header = f"{columns.time_column},{columns.upper_column},{columns.lower_column}"
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt=["%.7f", "%.6g", "%.6g"])
