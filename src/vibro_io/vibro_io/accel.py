"""Read ``accel.csv``: accelerometer samples of the upper and lower plates (m/s^2)."""

from __future__ import annotations

import csv
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vibro_model.errors import AccelError

from .rig import AccelConfig

log = logging.getLogger(__name__)


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


# Impacts are located in the accelerometer signal to a fraction of a camera frame: the DAQ must
# sample at several kHz and faster than the camera. Below this floor the time column is misread.
MIN_SAMPLE_RATE_HZ = 2_000.0
MAX_SAMPLE_RATE_HZ = 10e6  # beyond any DAQ for accelerometers


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


def load_accel(path: str | Path, columns: AccelConfig, camera_fps: float | None = None) -> AccelData:
    """Read an accelerometer CSV; refuses non-numeric or non-increasing times naming the line.

    A UTF-8 byte-order mark is accepted. A last line without a line end (the writer stopped
    mid-line) is dropped with a warning naming file and line. The sample rate implied by the
    time column (seconds) is checked: see :func:`check_sample_rate`.
    """
    path = Path(path)
    if columns.is_tdms:  # rig.yaml maps TDMS channels (vibro_io.tdms); without the camera's wall-clock start
        from .tdms import load_tdms_accel

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
    if len(rows) < 2:
        raise AccelError(f"{path}: fewer than 2 samples")
    data = np.asarray(rows, dtype=float)
    accel = AccelData(t_s=data[:, 0], upper_ms2=data[:, 1], lower_ms2=data[:, 2])
    check_sample_rate(accel.sample_rate_hz, f"{path}: column '{columns.time_column}'", camera_fps)
    for column, values in ((columns.upper_column, accel.upper_ms2), (columns.lower_column, accel.lower_ms2)):
        warn_if_clipped(values, f"{path}: column '{column}'")
    return accel


def check_sample_rate(rate_hz: float, where: str, camera_fps: float | None = None) -> None:
    """Refuse a sample rate (Hz, from a time column read as seconds) no accelerometer DAQ has.

    The plausible range is [max(MIN_SAMPLE_RATE_HZ, camera_fps), MAX_SAMPLE_RATE_HZ]: impacts
    need several kHz, and more than the camera's frame rate. A rate that becomes plausible
    when multiplied by 1000 or 1e6 means the column holds milliseconds or microseconds.
    """
    low = max(MIN_SAMPLE_RATE_HZ, camera_fps or 0.0)
    if low <= rate_hz <= MAX_SAMPLE_RATE_HZ:
        return
    need = (f"an accelerometer for impacts samples at several kHz (at least {low:g} Hz"
            + (f", faster than the camera's {camera_fps:g} fps" if camera_fps else "") + ")")
    hint = ""
    if rate_hz == 1.0:
        hint = "; samples are 1 apart: is the column a sample number instead of seconds?"
    elif rate_hz < low:
        for factor, unit in ((1e3, "milliseconds"), (1e6, "microseconds")):
            if low <= rate_hz * factor <= MAX_SAMPLE_RATE_HZ:
                hint = (f"; read as {unit} it would be {rate_hz * factor:g} Hz: "
                        f"is the time in {unit} instead of seconds?")
                break
    raise AccelError(f"{where}: the time column (seconds) implies {rate_hz:g} samples/s, but {need}{hint}")


#: This many consecutive samples or more at a channel's extreme value look like a saturated ADC/amplifier.
CLIP_RUN_SAMPLES = 3


def warn_if_clipped(values: np.ndarray, where: str) -> int:
    """Warn (naming ``where`` and the first sample) when the signal sits at its maximum or minimum for
    CLIP_RUN_SAMPLES samples or more in a row: a saturated sensor, amplifier or DAQ range flattens
    the impact peaks. Returns the number of such flat runs."""
    runs = 0
    first = None
    for extreme in (values.max(initial=-np.inf), values.min(initial=np.inf)):
        at = np.concatenate(([0], (values == extreme).astype(np.int8), [0]))
        edges = np.diff(at)
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        long = starts[(ends - starts) >= CLIP_RUN_SAMPLES]
        runs += long.size
        if long.size and (first is None or long[0] < first[0]):
            first = (int(long[0]), float(extreme))
    if first is not None:
        log.warning("%s: clipped? %d stretch(es) of >= %d samples sit at the signal's extreme value, first at "
                    "sample %d (value %g): a saturated sensor or DAQ range flattens impact peaks; check the range",
                    where, runs, CLIP_RUN_SAMPLES, first[0], first[1])
    return runs


def write_accel(path: str | Path, data: AccelData, columns: AccelConfig) -> None:
    """Write samples as CSV with the column names of ``columns``."""
    table = np.column_stack([data.t_s, data.upper_ms2, data.lower_ms2])
    header = f"{columns.time_column},{columns.upper_column},{columns.lower_column}"
    np.savetxt(path, table, delimiter=",", header=header, comments="", fmt=["%.7f", "%.6g", "%.6g"])
