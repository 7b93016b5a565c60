"""Accelerometer units as the instrument recorded them: TDMS unit strings, accel.csv's accelerometers.unit.

Every case goes through the app's entry (open_recording(...).load_accel(), or `vibro info`) on a
`vibro synth` recording whose accelerometers are rewritten as a TDMS file (npTDMS's TdmsWriter)
in the unit under test, or whose rig.yaml gives accel.csv a unit.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from vibro_app.cli import main
from vibro_io.accel import AccelData, load_accel, write_accel
from vibro_io.recording import open_recording
from vibro_io.rig import AccelConfig, AccelSensitivity, load_rig, parse_rig
from vibro_model.errors import AccelError, RigError

G_MPS2 = 9.80665  # standard gravity (m/s^2), exact by definition
#: The conversions below take a few float operations, each off by at most half an ulp (eps / 2):
#: eight eps bounds the relative difference between two orders of evaluation.
RTOL_ROUNDING = 8 * np.finfo(float).eps
#: write_accel prints 6 significant digits (%.6g): half a unit in the 6th digit, relative.
RTOL_SIX_DIGITS = 5e-6
DAQ_START = np.datetime64("2024-05-01T10:00:00.000000", "us")
CHANNELS = ("upper_plate", "lower_plate")
TDMS_BLOCK = {"file": "accel.tdms", "group": "accel", "upper_channel": CHANNELS[0], "lower_channel": CHANNELS[1]}
SENSITIVITY_KEY = "accelerometers.sensitivity_mv_per_g"


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> Path:
    from vibro_sim.synth import SynthConfig, synthesize

    out = tmp_path_factory.mktemp("units") / "rec"
    synthesize(out, SynthConfig(frames=40, seed=3), progress=False)
    return out


@pytest.fixture
def table(synth) -> np.ndarray:
    """The synthetic accel.csv: time (s), upper and lower plate (m/s^2)."""
    return np.loadtxt(synth / "accel.csv", delimiter=",", skiprows=1)


def _recording(synth: Path, dst: Path, accel: dict) -> Path:
    """A copy of the synthetic recording whose rig.yaml has ``accel`` as its accelerometers block."""
    shutil.copytree(synth, dst)
    rig = yaml.safe_load((dst / "rig.yaml").read_text())
    rig["accelerometers"] = accel
    (dst / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    return dst


def _write_tdms(path: Path, upper: np.ndarray, lower: np.ndarray, units: tuple[str | None, str | None],
                dt_s: float, unit_property: str = "unit_string", extra: dict | None = None) -> Path:
    """Two waveform channels in group 'accel'; ``units`` (None: no unit property) under ``unit_property``."""
    from nptdms import ChannelObject, TdmsWriter

    channels = []
    for name, values, unit in zip(CHANNELS, (upper, lower), units):
        props = {"wf_increment": dt_s, "wf_start_time": DAQ_START, "wf_start_offset": 0.0, "wf_samples": len(values)}
        if unit is not None:
            props[unit_property] = unit
        props.update(extra or {})
        channels.append(ChannelObject("accel", name, values, properties=props))
    with TdmsWriter(str(path)) as writer:
        writer.write_segment(channels)
    return path


def _tdms_recording(synth: Path, dst: Path, upper: np.ndarray, lower: np.ndarray,
                    units: tuple[str | None, str | None], dt_s: float = 2e-5, unit_property: str = "unit_string",
                    extra: dict | None = None, **rig_keys: object) -> Path:
    """The synthetic recording with accel.tdms (``units``) and rig.yaml's TDMS block plus ``rig_keys``."""
    rec = _recording(synth, dst, dict(TDMS_BLOCK, **rig_keys))
    _write_tdms(rec / "accel.tdms", upper, lower, units, dt_s, unit_property, extra)
    return rec


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# --- TDMS -------------------------------------------------------------------------------------

@pytest.mark.parametrize("unit, mv_per_unit", [("Volts", 1000.0), ("V", 1000.0), ("mV", 1.0), ("millivolts", 1.0)])
def test_tdms_in_volts_is_converted_with_the_sensitivity(synth, table, tmp_path, unit, mv_per_unit) -> None:
    sens = 100.0  # mV per g, a typical IEPE accelerometer
    recorded = table[:, 1:] / G_MPS2 * sens / mv_per_unit  # what the DAQ recorded, in `unit`
    rec = _tdms_recording(synth, tmp_path / "rec", recorded[:, 0], recorded[:, 1], (unit, unit),
                          sensitivity_mv_per_g=sens)
    accel = open_recording(rec).load_accel()
    expected = recorded * mv_per_unit / sens * G_MPS2
    np.testing.assert_allclose(accel.upper_ms2, expected[:, 0], rtol=RTOL_ROUNDING, atol=0)
    np.testing.assert_allclose(accel.lower_ms2, expected[:, 1], rtol=RTOL_ROUNDING, atol=0)
    np.testing.assert_allclose(accel.upper_ms2, table[:, 1], rtol=RTOL_ROUNDING, atol=0)
    assert accel.source_unit == unit and accel.unit_source == "unit_string"
    assert accel.mps2_per_source_unit == pytest.approx((mv_per_unit / sens * G_MPS2,) * 2, rel=RTOL_ROUNDING)


@pytest.mark.parametrize("unit", ["g", "G", "g0", "gn"])
def test_tdms_in_g_is_multiplied_by_standard_gravity(synth, table, tmp_path, unit) -> None:
    in_g = table[:, 1:] / G_MPS2
    rec = _tdms_recording(synth, tmp_path / "rec", in_g[:, 0], in_g[:, 1], (unit, unit))
    accel = open_recording(rec).load_accel()
    np.testing.assert_allclose(accel.upper_ms2, in_g[:, 0] * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    np.testing.assert_allclose(accel.lower_ms2, in_g[:, 1] * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    assert accel.source_unit == unit and accel.mps2_per_source_unit == (G_MPS2, G_MPS2)


@pytest.mark.parametrize("unit", ["m/s^2", "m/s\u00b2", "M/S2", "m s^-2", "m/(s^2)"])
def test_tdms_in_metres_per_second_squared_is_taken_as_is(synth, table, tmp_path, unit) -> None:
    rec = _tdms_recording(synth, tmp_path / "rec", table[:, 1], table[:, 2], (unit, unit))
    accel = open_recording(rec).load_accel()
    np.testing.assert_array_equal(accel.upper_ms2, table[:, 1])
    np.testing.assert_array_equal(accel.lower_ms2, table[:, 2])
    assert accel.source_unit == unit and accel.mps2_per_source_unit == (1.0, 1.0)


def test_per_channel_sensitivities_and_units(synth, table, tmp_path) -> None:
    # upper sensor 100 mV/g recorded in V, lower sensor 10.2 mV/g recorded in mV
    upper_v = table[:, 1] / G_MPS2 * 100.0 / 1000.0
    lower_mv = table[:, 2] / G_MPS2 * 10.2
    rec = _tdms_recording(synth, tmp_path / "rec", upper_v, lower_mv, ("Volts", "mV"),
                          sensitivity_mv_per_g={"upper": 100.0, "lower": 10.2})
    accel = open_recording(rec).load_accel()
    np.testing.assert_allclose(accel.upper_ms2, upper_v * 1000.0 / 100.0 * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    np.testing.assert_allclose(accel.lower_ms2, lower_mv / 10.2 * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    assert accel.source_units == ("Volts", "mV") and accel.source_unit == "upper: Volts, lower: mV"


def test_volts_without_a_sensitivity_are_refused_naming_channel_unit_and_key(synth, table, tmp_path, capsys) -> None:
    rec = _tdms_recording(synth, tmp_path / "rec", table[:, 1], table[:, 2], ("Volts", "Volts"))
    with pytest.raises(AccelError) as err:
        open_recording(rec).load_accel()
    for word in ("accel.tdms", "channel 'accel/upper_plate'", "'Volts'", SENSITIVITY_KEY):
        assert word in str(err.value), (word, str(err.value))
    assert main(["info", str(rec)]) == 2
    line = _one_line_error(capsys)
    assert "'Volts'" in line and SENSITIVITY_KEY in line


def test_an_unknown_unit_is_refused_naming_it(synth, table, tmp_path, capsys) -> None:
    rec = _tdms_recording(synth, tmp_path / "rec", table[:, 1], table[:, 2], ("m/s^2", "furlongs"))
    with pytest.raises(AccelError, match=r"accel\.tdms: channel 'accel/lower_plate': unit 'furlongs'"):
        open_recording(rec).load_accel()
    assert main(["info", str(rec)]) == 2
    assert "furlongs" in _one_line_error(capsys)


def test_ni_unit_description_is_read_and_contradicting_unit_properties_refused(synth, table, tmp_path) -> None:
    in_g = table[:, 1:] / G_MPS2
    rec = _tdms_recording(synth, tmp_path / "desc", in_g[:, 0], in_g[:, 1], ("g", "g"),
                          unit_property="NI_UnitDescription")
    accel = open_recording(rec).load_accel()
    np.testing.assert_allclose(accel.upper_ms2, in_g[:, 0] * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    assert accel.unit_source == "NI_UnitDescription"

    rec = _tdms_recording(synth, tmp_path / "clash", in_g[:, 0], in_g[:, 1], ("g", "g"),
                          extra={"NI_UnitDescription": "Volts"})
    with pytest.raises(AccelError, match=r"unit properties disagree.*unit_string 'g'.*NI_UnitDescription 'Volts'"):
        open_recording(rec).load_accel()


def test_channels_without_a_unit_are_taken_as_m_s2_with_one_warning(synth, table, tmp_path, caplog) -> None:
    rec = _tdms_recording(synth, tmp_path / "rec", table[:, 1], table[:, 2], (None, None))
    with caplog.at_level(logging.INFO):
        accel = open_recording(rec).load_accel()
    np.testing.assert_array_equal(accel.upper_ms2, table[:, 1])
    assert accel.unit_source == "assumed" and accel.source_unit == "m/s^2"
    lines = [r.message for r in caplog.records if "no unit" in r.message]
    assert len(lines) == 1 and "'accel/upper_plate'" in lines[0] and "'accel/lower_plate'" in lines[0]
    assert "m/s^2" in lines[0] and "accelerometers.unit" in lines[0]


def test_rig_unit_fills_in_for_a_tdms_without_one_and_must_agree_with_one(synth, table, tmp_path) -> None:
    in_g = table[:, 1:] / G_MPS2
    rec = _tdms_recording(synth, tmp_path / "fill", in_g[:, 0], in_g[:, 1], (None, None), unit="g")
    accel = open_recording(rec).load_accel()
    np.testing.assert_allclose(accel.lower_ms2, in_g[:, 1] * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    assert accel.unit_source == "accelerometers.unit" and accel.source_unit == "g"

    rec = _tdms_recording(synth, tmp_path / "clash", in_g[:, 0], in_g[:, 1], ("g", "g"), unit="V",
                          sensitivity_mv_per_g=100)
    with pytest.raises(AccelError, match=r"channel 'accel/upper_plate': the file records unit 'g'.*"
                                         r"accelerometers\.unit says V"):
        open_recording(rec).load_accel()


def test_a_1_khz_tdms_names_its_wf_increment_not_milliseconds(synth, table, tmp_path, capsys) -> None:
    rec = _tdms_recording(synth, tmp_path / "rec", table[::50, 1], table[::50, 2], ("m/s^2", "m/s^2"), dt_s=1e-3)
    with pytest.raises(AccelError) as err:
        open_recording(rec).load_accel()
    msg = str(err.value)
    assert "channel 'accel/upper_plate'" in msg and "wf_increment 0.001 s" in msg and "1000 samples/s" in msg, msg
    assert "millisecond" not in msg and "time column" not in msg, msg
    assert main(["info", str(rec)]) == 2
    line = _one_line_error(capsys)
    assert "wf_increment" in line and "millisecond" not in line


# --- accel.csv ---------------------------------------------------------------------------------

def _csv_block(**keys: object) -> dict:
    return dict({"file": "accel.csv", "time_column": "time_s", "upper_column": "upper_ms2",
                 "lower_column": "lower_ms2"}, **keys)


def test_csv_in_g_is_converted(synth, table, tmp_path) -> None:
    rec = _recording(synth, tmp_path / "rec", _csv_block(unit="g"))
    accel = open_recording(rec).load_accel()
    np.testing.assert_allclose(accel.upper_ms2, table[:, 1] * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    np.testing.assert_allclose(accel.lower_ms2, table[:, 2] * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    assert accel.source_unit == "g" and accel.unit_source == "accelerometers.unit"
    np.testing.assert_array_equal(accel.t_s, table[:, 0])


def test_csv_in_millivolts_uses_each_sensors_sensitivity(synth, table, tmp_path) -> None:
    rec = _recording(synth, tmp_path / "rec", _csv_block(unit="mV", sensitivity_mv_per_g={"upper": 50, "lower": 20}))
    accel = open_recording(rec).load_accel()
    np.testing.assert_allclose(accel.upper_ms2, table[:, 1] / 50 * G_MPS2, rtol=RTOL_ROUNDING, atol=0)
    np.testing.assert_allclose(accel.lower_ms2, table[:, 2] / 20 * G_MPS2, rtol=RTOL_ROUNDING, atol=0)


def test_csv_without_unit_is_m_s2_by_default(synth, table, tmp_path) -> None:
    accel = open_recording(_recording(synth, tmp_path / "rec", _csv_block())).load_accel()
    np.testing.assert_array_equal(accel.upper_ms2, table[:, 1])
    assert accel.source_unit == "m/s^2" and accel.unit_source == "default"


def test_write_accel_writes_in_the_configured_unit_and_reads_back(tmp_path) -> None:
    t = np.arange(100) / 20_000.0
    data = AccelData(t, 30.0 * np.sin(t * 2e3), -12.0 * np.cos(t * 2e3))
    cols = AccelConfig(file="a.csv", time_column="time_s", upper_column="up", lower_column="low", unit="V",
                       sensitivity_mv_per_g=AccelSensitivity(100.0, 10.0))
    write_accel(tmp_path / "a.csv", data, cols)
    raw = np.loadtxt(tmp_path / "a.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(raw[:, 1], data.upper_ms2 / G_MPS2 * 100.0 / 1000.0, rtol=RTOL_SIX_DIGITS, atol=0)
    back = load_accel(tmp_path / "a.csv", cols)
    np.testing.assert_allclose(back.upper_ms2, data.upper_ms2, rtol=RTOL_SIX_DIGITS, atol=0)
    np.testing.assert_allclose(back.lower_ms2, data.lower_ms2, rtol=RTOL_SIX_DIGITS, atol=0)


@pytest.mark.parametrize("keys, words", [
    ({"unit": "furlongs"}, ["key 'accelerometers.unit'", "furlongs", "m/s^2, g, V, mV"]),
    ({"unit": "V"}, ["key 'accelerometers.unit' is V", SENSITIVITY_KEY]),
    ({"unit": "mV", "sensitivity_mv_per_g": -5}, [f"key '{SENSITIVITY_KEY}'", "positive", "-5"]),
    ({"unit": "V", "sensitivity_mv_per_g": {"upper": 100}}, [f"'{SENSITIVITY_KEY}.lower'"]),
    ({"unit": "V", "sensitivity_mv_per_g": {"upper": 100, "lower": 100, "uper": 1}}, [f"'{SENSITIVITY_KEY}.uper'"]),
    ({"unit": "V", "sensitivity_mv_per_g": {"upper": 100, "lower": "ten"}}, [f"'{SENSITIVITY_KEY}.lower'", "ten"]),
])
def test_csv_unit_keys_are_validated_naming_file_and_key(synth, tmp_path, capsys, keys, words) -> None:
    rec = _recording(synth, tmp_path / "rec", _csv_block(**keys))
    with pytest.raises(RigError) as err:
        load_rig(rec / "rig.yaml")
    assert "rig.yaml" in str(err.value)
    for word in words:
        assert word in str(err.value), (word, str(err.value))
    assert main(["info", str(rec)]) == 2
    assert words[0] in _one_line_error(capsys)


def test_a_sensitivity_csv_never_uses_is_warned_about(synth, tmp_path, caplog) -> None:
    rec = _recording(synth, tmp_path / "rec", _csv_block(sensitivity_mv_per_g=100))
    with caplog.at_level(logging.WARNING):
        load_rig(rec / "rig.yaml")
    assert f"'{SENSITIVITY_KEY}' not used" in caplog.text


@pytest.mark.parametrize("sens", [100.0, {"upper": 100.0, "lower": 10.2}])
def test_unit_and_sensitivity_survive_the_rig_round_trip(synth, tmp_path, sens) -> None:
    rec = _recording(synth, tmp_path / "rec", _csv_block(unit="V", sensitivity_mv_per_g=sens))
    rig = load_rig(rec / "rig.yaml")
    assert rig.accelerometers.unit == "V"
    assert rig.to_dict()["accelerometers"]["sensitivity_mv_per_g"] == sens
    assert parse_rig(rig.to_dict()).accelerometers == rig.accelerometers
