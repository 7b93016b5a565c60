"""accel.csv reading: values, sample rate, and refusals that name the line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vibro_io.accel import AccelData, load_accel, write_accel
from vibro_io.rig import AccelConfig
from vibro_model.errors import AccelError

COLS = AccelConfig(file="accel.csv", time_column="time_s", upper_column="upper_ms2", lower_column="lower_ms2")


def test_fixture_accel(tiny_recording: Path) -> None:
    data = load_accel(tiny_recording / "accel.csv", COLS)
    assert len(data) == 250
    assert data.sample_rate_hz == pytest.approx(50_000.0, rel=1e-6)
    # the fixture holds gravity plus a 0.5 m/s^2 sine: the mean is -9.81 within the sine's bias
    assert abs(np.mean(data.upper_ms2) + 9.81) < 0.5


def test_round_trip(tmp_path: Path) -> None:
    t = np.arange(100) / 50_000.0
    data = AccelData(t, np.sin(t * 1e3), np.cos(t * 1e3))
    write_accel(tmp_path / "a.csv", data, COLS)
    again = load_accel(tmp_path / "a.csv", COLS)
    np.testing.assert_allclose(again.upper_ms2, data.upper_ms2, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("body,message", [
    ("time_s,upper_ms2,lower_ms2\n0.0,1,2\n0.00002,x,2\n", r"line 3: non-numeric"),
    ("time_s,upper_ms2,lower_ms2\n0.0,1,2\n0.00002,1,2\n0.00001,1,2\n", r"line 4: time 1e-05 s does not increase"),
    ("time_s,upper_ms2,lower_ms2\n0.0,1,2\n0.0,1,2\n", r"line 3: time 0.0 s does not increase"),
    ("time_s,upper,lower_ms2\n0.0,1,2\n", r"line 1: column 'upper_ms2' not found"),
    ("", r"empty file"),
    ("time_s,upper_ms2,lower_ms2\n0.0,1,nan\n", r"line 2: non-finite"),
    ("time_s,upper_ms2,lower_ms2\n0.0,1\n", r"line 2: non-numeric or missing"),
])
def test_bad_csv_is_refused_with_line_number(tmp_path: Path, body: str, message: str) -> None:
    path = tmp_path / "accel.csv"
    path.write_text(body)
    with pytest.raises(AccelError, match=message):
        load_accel(path, COLS)


def test_the_whole_file_reader_and_the_line_reader_agree(tmp_path: Path) -> None:
    """numpy's C reader (well-formed files) and the line-by-line reader (which names bad lines) give the same
    numbers, column order and all, on a file with a BOM, reordered and extra columns, spaces and a blank line."""
    import csv

    from vibro_io.accel import _rows_line_by_line, _whole_file_rows

    rng = np.random.default_rng(3)
    t = np.arange(500) / 50_000.0
    up, low = rng.normal(0, 30, 500), rng.normal(0, 30, 500)
    lines = ["\ufefflower_ms2,extra,time_s,upper_ms2"]
    lines += [f"{float(b)!r}, 7 ,{a:.7f},{float(u)!r}" for a, u, b in zip(t, up, low)]
    lines.insert(200, "")
    path = tmp_path / "a.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    idx = [2, 3, 0]
    whole = _whole_file_rows(path, idx)
    with path.open(newline="", encoding="utf-8-sig") as handle:
        reader = csv.reader(handle)
        next(reader)
        by_line = _rows_line_by_line(path, reader, idx, True)
    assert whole is not None and whole.shape == (500, 3)
    np.testing.assert_array_equal(whole, by_line)
    np.testing.assert_array_equal(whole[:, 1], up)  # repr round-trips: bit for bit
    np.testing.assert_array_equal(whole[:, 2], low)
    # a file the C reader cannot take whole is left to the line reader
    path.write_text("time_s,upper_ms2,lower_ms2\n0.0,1,2\n0.00002,x,2\n", encoding="utf-8")
    assert _whole_file_rows(path, [0, 1, 2]) is None
