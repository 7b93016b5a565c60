"""accel.csv as DAQs really leave it, and recording files that try to leave the recording, on `vibro synth` data.

Truncated last line (a crash mid-write), UTF-8 byte-order mark, time in milliseconds; accelerometer,
frame and video paths that are absolute, climb out with '..' or are symlinks to outside.
"""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from vibro_app.cli import main
from vibro_io.accel import load_accel
from vibro_io.dictrack import FrameTrack, write_dic_csv
from vibro_io.recording import open_recording
from vibro_model.errors import AccelError, RecordingError

N_FRAMES = 300


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> Path:
    from vibro_sim.synth import SynthConfig, synthesize

    out = tmp_path_factory.mktemp("accel") / "rec"
    synthesize(out, SynthConfig(frames=N_FRAMES, seed=12), progress=False)
    return out


@pytest.fixture
def rec(synth, tmp_path) -> Path:
    dst = tmp_path / "rec"
    shutil.copytree(synth, dst)
    return dst


def _original_table(rec: Path) -> np.ndarray:
    return np.loadtxt(rec / "accel.csv", delimiter=",", skiprows=1)


def _set_accel_file(rec: Path, name: str) -> None:
    rig = yaml.safe_load((rec / "rig.yaml").read_text())
    rig["accelerometers"]["file"] = name
    (rec / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# --- item 3: accel.csv contents ---------------------------------------------------------------

@pytest.mark.parametrize("cut", ["mid_second_value", "mid_last_value"])
def test_truncated_last_line_keeps_the_complete_rows_and_warns(rec, caplog, cut: str) -> None:
    # The DAQ crashed while writing the last row: no line end. The complete rows are kept, the partial
    # one dropped (a cut inside the last value would parse as a wrong number), with file and line named.
    table = _original_table(rec)
    text = (rec / "accel.csv").read_text()
    lines = text.rstrip("\n").split("\n")
    last = lines[-1]
    cut_at = last.index(",") + 3 if cut == "mid_second_value" else len(last) - 2
    (rec / "accel.csv").write_text("\n".join(lines[:-1] + [last[:cut_at]]))
    with caplog.at_level(logging.WARNING):
        data = open_recording(rec).load_accel()
    assert len(data) == table.shape[0] - 1
    np.testing.assert_array_equal(np.column_stack([data.t_s, data.upper_ms2, data.lower_ms2]), table[:-1])
    assert f"accel.csv: line {len(lines)}: last line has no line end" in caplog.text


def test_byte_order_mark_is_accepted(rec) -> None:
    table = _original_table(rec)
    raw = (rec / "accel.csv").read_bytes()
    (rec / "accel.csv").write_bytes(b"\xef\xbb\xbf" + raw)
    data = open_recording(rec).load_accel()
    np.testing.assert_array_equal(data.upper_ms2, table[:, 1])


def test_time_in_milliseconds_is_named(rec, capsys) -> None:
    # 50 kHz written in ms reads as 50 Hz: refused naming file, column and the likely unit
    table = _original_table(rec)
    table[:, 0] *= 1e3
    np.savetxt(rec / "accel.csv", table, delimiter=",", header="time_s,upper_ms2,lower_ms2", comments="",
               fmt=["%.7f", "%.6g", "%.6g"])
    with pytest.raises(AccelError, match=r"accel.csv: column 'time_s': the time column \(seconds\) implies 50 "
                                         r"samples/s.*is the time in milliseconds instead of seconds\?"):
        open_recording(rec).load_accel()
    assert main(["info", str(rec)]) == 2
    assert "milliseconds" in _one_line_error(capsys)


def test_accelerometers_slower_than_the_camera_are_refused(rec) -> None:
    # 50 kHz samples against a camera said to run at 100 kfps
    rig = yaml.safe_load((rec / "rig.yaml").read_text())
    rig["camera"]["fps"] = 100_000.0
    (rec / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    with pytest.raises(AccelError, match=r"column 'time_s'.*faster than the camera's 100000 fps"):
        open_recording(rec).load_accel()


def test_plain_load_accel_refuses_a_sample_number_column(rec) -> None:
    table = _original_table(rec)[:500]
    table[:, 0] = np.arange(len(table))
    np.savetxt(rec / "accel.csv", table, delimiter=",", header="time_s,upper_ms2,lower_ms2", comments="")
    with pytest.raises(AccelError, match="sample number instead of seconds"):
        load_accel(rec / "accel.csv", open_recording(rec).rig.accelerometers)


# --- item 4: paths stay inside the recording --------------------------------------------------

@pytest.mark.parametrize("name", ["/etc/passwd", "../accel.csv", "sub/../../accel.csv"])
def test_accel_file_outside_the_recording_is_refused_unread(rec, capsys, name: str) -> None:
    shutil.copy(rec / "accel.csv", rec.parent / "accel.csv")  # a readable CSV one level up
    _set_accel_file(rec, name)
    with pytest.raises(RecordingError, match=r"key 'accelerometers.file'.*expected a file name relative"):
        open_recording(rec)
    assert main(["info", str(rec)]) == 2
    err = _one_line_error(capsys)
    assert "accelerometers.file" in err and name in err and "root:" not in err


def test_accel_symlink_to_outside_is_refused(rec, capsys) -> None:
    outside = rec.parent / "elsewhere.csv"
    shutil.move(rec / "accel.csv", outside)
    os.symlink(outside, rec / "accel.csv")
    with pytest.raises(RecordingError, match=r"key 'accelerometers.file' names accel.csv, which leads outside"):
        open_recording(rec)
    assert main(["info", str(rec)]) == 2
    _one_line_error(capsys)
    # a link that stays inside the recording is no escape: accepted
    shutil.move(outside, rec / "daq_run1.csv")
    (rec / "accel.csv").unlink()
    os.symlink("daq_run1.csv", rec / "accel.csv")
    assert len(open_recording(rec).load_accel()) == len(_original_table(rec))


def test_analyze_with_a_given_track_refuses_outside_accel(rec, tmp_path, capsys) -> None:
    # the --track path reads rig.yaml and accel.csv without opening the frames: same refusal
    dic = tmp_path / "dic.csv"
    write_dic_csv(dic, [FrameTrack(frame=k, t_s=k / 1000.0, ball_mm=0.0, structure_mm=0.0, ball_valid=9,
                                   structure_valid=9, ball_zncc=0.99, structure_zncc=0.99,
                                   lost=False) for k in range(30)])
    _set_accel_file(rec, "/etc/passwd")
    assert main(["analyze", str(rec), "--out", str(tmp_path / "o"), "--track", str(dic), "--no-progress"]) == 2
    err = _one_line_error(capsys)
    assert "accelerometers.file" in err and "root:" not in err


def test_frames_folder_symlink_to_outside_is_refused(rec) -> None:
    shutil.move(rec / "frames", rec.parent / "frames_elsewhere")
    os.symlink(rec.parent / "frames_elsewhere", rec / "frames")
    with pytest.raises(RecordingError, match="frames folder names frames, which leads outside"):
        open_recording(rec)


def test_frame_file_symlink_to_outside_is_refused(rec) -> None:
    frame = rec / "frames" / "000007.png"
    shutil.move(frame, rec.parent / "000007.png")
    os.symlink(rec.parent / "000007.png", frame)
    with pytest.raises(RecordingError, match="frame file 000007.png names frames/000007.png, which leads outside"):
        open_recording(rec)


def test_video_symlink_to_outside_is_refused(rec) -> None:
    shutil.rmtree(rec / "frames")
    (rec.parent / "movie.avi").write_bytes(b"not really a video")
    os.symlink(rec.parent / "movie.avi", rec / "video.avi")
    with pytest.raises(RecordingError, match="video file names video.avi, which leads outside"):
        open_recording(rec)
