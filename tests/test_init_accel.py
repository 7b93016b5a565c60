"""``vibro init`` names the accelerometer file beside the video in rig.yaml, or refuses to guess.

A lab types the ball's diameter and the gap; its DAQ's file sits beside the video. Before, init wrote no
``accelerometers`` block and the analysis ran on the video alone with exit code 0. The end-to-end path (a TDMS
found, analysed) is in tests/test_synth_lab_files.py; here each rule on small real files (npTDMS, csv).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from lab_writers import write_tdms

from vibro_app.init_accel import AccelRequest, choose_accel
from vibro_io.rig import AccelConfig
from vibro_model.errors import RecordingError


def _tdms(folder: Path, names: tuple[str, str], group: str = "accel", name: str = "daq.tdms") -> Path:
    folder.mkdir(exist_ok=True)
    x = np.zeros(100)
    return write_tdms(folder / name, x, x, 2e-5, np.datetime64("2026-11-27T12:00:00"), group=group, names=names)


def _csv(folder: Path, header: str) -> Path:
    folder.mkdir(exist_ok=True)
    path = folder / "accel.csv"
    path.write_text(header + "\n0.0,0.1,0.2\n")
    return path


def _block(choice) -> dict:
    return yaml.safe_load(choice.yaml())["accelerometers"]


def test_a_tdms_with_named_plates_is_written_as_the_loader_reads_it(tmp_path: Path) -> None:
    _tdms(tmp_path, ("Upper plate", "Lower plate"), group="Accelerometers")
    block = _block(choose_accel(tmp_path, AccelRequest()))
    assert block == {"file": "daq.tdms", "group": "Accelerometers", "upper_channel": "Upper plate",
                     "lower_channel": "Lower plate"}
    assert AccelConfig(**block).file == "daq.tdms"  # the keys the rig.yaml reader takes


def test_a_csv_with_the_contract_header_and_one_in_g(tmp_path: Path) -> None:
    _csv(tmp_path / "a", "time_s,upper_ms2,lower_ms2")
    assert _block(choose_accel(tmp_path / "a", AccelRequest())) == {
        "file": "accel.csv", "time_column": "time_s", "upper_column": "upper_ms2", "lower_column": "lower_ms2"}
    _csv(tmp_path / "b", "Time,top_g,bottom_g")
    assert _block(choose_accel(tmp_path / "b", AccelRequest()))["unit"] == "g"


def test_names_that_do_not_say_which_plate_are_refused_with_the_names_there_are(tmp_path: Path) -> None:
    _tdms(tmp_path, ("ai0", "ai1"))
    with pytest.raises(RecordingError, match=r"upper plate's channel.*ai0, ai1.*--accel-upper"):
        choose_accel(tmp_path, AccelRequest())
    # the user says it
    block = _block(choose_accel(tmp_path, AccelRequest(upper="ai1", lower="ai0")))
    assert (block["upper_channel"], block["lower_channel"]) == ("ai1", "ai0")
    with pytest.raises(RecordingError, match=r"no upper plate's channel 'ai7'"):
        choose_accel(tmp_path, AccelRequest(upper="ai7", lower="ai0"))


def test_volts_need_a_calibration_init_cannot_know(tmp_path: Path) -> None:
    _csv(tmp_path, "time_s,upper_v,lower_v")
    with pytest.raises(RecordingError, match="sensitivity_mv_per_g"):
        choose_accel(tmp_path, AccelRequest())


def test_several_files_or_none(tmp_path: Path) -> None:
    assert choose_accel(tmp_path, AccelRequest()) is None  # nothing there: video only
    _tdms(tmp_path, ("upper", "lower"), name="take1.tdms")
    _tdms(tmp_path, ("upper", "lower"), name="take2.TDMS")
    with pytest.raises(RecordingError, match=r"several accelerometer files \(take1.tdms, take2.TDMS\).*--accel"):
        choose_accel(tmp_path, AccelRequest())
    assert _block(choose_accel(tmp_path, AccelRequest(file="take2.TDMS")))["file"] == "take2.TDMS"
    assert choose_accel(tmp_path, AccelRequest(none=True)) is None


def test_a_damaged_tdms_is_named_not_a_traceback(tmp_path: Path) -> None:
    (tmp_path / "daq.tdms").write_bytes(b"TDSm" + bytes(20))  # a lead-in and nothing in it
    with pytest.raises(RecordingError, match=r"daq.tdms: (not a readable TDMS file|no channel in the TDMS file)"):
        choose_accel(tmp_path, AccelRequest())
    (tmp_path / "daq.tdms").write_bytes(b"not a TDMS file at all, cut short")
    with pytest.raises(RecordingError, match=r"daq.tdms: (not a readable TDMS file|no channel in the TDMS file)"):
        choose_accel(tmp_path, AccelRequest())
