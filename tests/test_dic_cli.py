"""``vibro track`` / ``vibro noise`` and the streaming ``track_recording`` on recordings on disk."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from vibro_app.cli import main
from vibro_dic.speckle import RigScene, write_scene_recording
from vibro_dic.tracker import track_recording
from vibro_io.dictrack import DIC_COLUMNS, read_dic_csv
from vibro_io.recording import open_recording

MM_PER_PX = 0.05
N = 60


@pytest.fixture(scope="module")
def moving(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, np.ndarray]:
    rec = tmp_path_factory.mktemp("dic") / "moving"
    k = np.arange(N)
    ball = 20.0 * np.sin(2 * np.pi * 22.0 * k / 1000.0) + 0.004 * k**2  # px up
    structure = 6.0 * np.sin(2 * np.pi * 22.0 * k / 1000.0 + 0.3)
    structure = structure - structure[0]
    write_scene_recording(rec, RigScene(seed=21), ball, structure, noise_sigma=2.0, mm_per_px=MM_PER_PX)
    (rec / "frames" / "000031.png").unlink()  # a dropped frame
    return rec, ball, structure


def test_track_writes_contract_csv_matching_truth(moving, tmp_path: Path, capsys) -> None:
    rec, ball, structure = moving
    out = tmp_path / "out"
    assert main(["track", str(rec), "--out", str(out), "--no-progress"]) == 0
    summary = capsys.readouterr().out
    assert f"{N} frames in, {N - 1} tracked, 1 lost" in summary
    header = (out / "dic.csv").read_text().splitlines()[0]
    assert tuple(header.split(",")) == DIC_COLUMNS
    tr = read_dic_csv(out / "dic.csv")
    assert len(tr) == N and list(tr.frame) == list(range(N))
    assert np.allclose(tr.t_s, np.arange(N) / 1000.0)
    assert tr.lost[31] and math.isnan(tr.ball_mm[31]) and tr.ball_valid[31] == 0
    good = tr.good
    assert good.sum() == N - 1
    # positive up, mm since frame 0; 8-bit PNG + sigma 2 noise: ~0.003 px per mesh (accuracy
    # tests), 0.01 px is the accuracy goal -> 0.01 px = 5e-4 mm here. The max over 59 frames of
    # an error of std ~0.003 px stays under ~3.5 std ~ 0.011 px: bound the max by 0.02 px
    assert np.abs(tr.ball_mm[good] - (ball[good] - ball[0]) * MM_PER_PX).max() <= 0.01 * MM_PER_PX * 2
    assert np.sqrt(np.mean((tr.structure_mm[good] - structure[good] * MM_PER_PX) ** 2)) <= 0.01 * MM_PER_PX
    assert np.all(tr.ball_valid[good] == 16) and np.all(tr.structure_valid[good] == 24)


def test_parabolic_method_from_cli(moving, tmp_path: Path) -> None:
    rec, ball, _ = moving
    assert main(["track", str(rec), "--out", str(tmp_path), "--method", "parabolic", "--no-progress"]) == 0
    tr = read_dic_csv(tmp_path / "dic.csv")
    g = tr.good
    # peak locking of the parabola is ~0.015 px at worst (accuracy tests): within 0.05 px
    assert np.abs(tr.ball_mm[g] - (ball[g] - ball[0]) * MM_PER_PX).max() <= 0.05 * MM_PER_PX


def test_track_recording_streams_lazily(moving) -> None:
    rec, _, _ = moving
    it = track_recording(open_recording(rec))
    first = next(it)  # a generator: frames are read as rows are asked for
    assert first.frame == 0 and abs(first.ball_mm) < 1e-6 and not first.lost
    assert sum(1 for _ in it) == N - 1


def test_noise_study_of_a_motionless_recording(tmp_path: Path, capsys) -> None:
    rec = tmp_path / "still"
    write_scene_recording(rec, RigScene(seed=22), np.zeros(120), np.zeros(120), noise_sigma=2.0)
    js = tmp_path / "noise.json"
    assert main(["noise", str(rec), "--json", str(js), "--no-progress"]) == 0
    assert "split at 50 Hz" in capsys.readouterr().out
    study = json.loads(js.read_text())
    for body in ("ball", "structure"):
        s = study[body]
        # sigma = 2 gray noise: per-mesh std ~0.003 px (accuracy tests) -> well under 0.01 px, not 0
        assert 1e-4 < s["std_px"] < 0.01
        # white image noise puts ~90 % of its variance above 50 Hz (of 500 Hz): high > low
        assert s["high_std_px"] > 2.0 * s["low_std_px"]
        assert s["std_mm"] == pytest.approx(s["std_px"] * 0.05)


def test_bad_recordings_give_one_line_errors(tmp_path: Path, moving, capsys) -> None:
    assert main(["track", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "not a recording directory" in err and "Traceback" not in err
    rec, _, _ = moving
    bad = tmp_path / "bad"
    bad.mkdir()
    shutil.copytree(rec / "frames", bad / "frames")  # a symlink leading out of the recording is refused
    rig = yaml.safe_load((rec / "rig.yaml").read_text())
    rig["dic"]["ball_roi"] = [450, 50, 61, 61]  # beyond the 480 px wide image
    (bad / "rig.yaml").write_text(yaml.safe_dump(rig))
    assert main(["track", str(bad), "--out", str(tmp_path / "o2")]) == 2
    assert "dic.ball_roi" in capsys.readouterr().err
    # a reference frame that cannot be decoded is named
    broken = tmp_path / "broken"
    (broken / "frames").mkdir(parents=True)
    (broken / "rig.yaml").write_text((rec / "rig.yaml").read_text())
    for k in range(3):
        (broken / "frames" / f"{k:06d}.png").write_bytes((rec / "frames" / f"{k:06d}.png").read_bytes())
    (broken / "frames" / "000000.png").write_bytes(b"not a png")
    assert main(["track", str(broken), "--out", str(tmp_path / "o3")]) == 2
    assert "000000.png" in capsys.readouterr().err
