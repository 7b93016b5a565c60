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
