"""Frame names (docs/recording-format.md, "Frame names") and unreadable frames, on a `vibro synth` recording.

The frame number is the one integer in the name that changes across the files; frame k is at
t0_s + k/fps. Checked against the synthetic truth (frame times, pixels of the original files,
true displacements), never against the code's own output.
"""

from __future__ import annotations

import csv
import json
import logging
import re
import shutil
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest

from vibro_app.cli import main
from vibro_io.recording import open_recording
from vibro_model.errors import FrameError
from vibro_sim.synth import SynthConfig, synthesize

N_FRAMES = 300
RULE = "frame files must share one name pattern"


@pytest.fixture(scope="module")
def synth(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("naming") / "rec"
    truth = synthesize(out, SynthConfig(frames=N_FRAMES, seed=11), progress=False)
    return out, truth


def _copy(src: Path, dst: Path, rename: Callable[[int], str] | None = None, keep=range(N_FRAMES)) -> Path:
    """Copy the recording, keeping frames ``keep`` and naming frame k ``rename(k)``."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("frames"))
    (dst / "frames").mkdir()
    for k in keep:
        name = rename(k) if rename else f"{k:06d}.png"
        shutil.copy(src / "frames" / f"{k:06d}.png", dst / "frames" / name)
    return dst


def _original(synth_dir: Path, k: int) -> np.ndarray:
    return cv2.imread(str(synth_dir / "frames" / f"{k:06d}.png"), cv2.IMREAD_UNCHANGED)


def test_prefixed_names_with_a_gap_keep_every_time(synth, tmp_path) -> None:
    # img_000123.png style, frame 150 dropped: used to be undetected (later frames 1 ms early)
    src, truth = synth
    rec = _copy(src, tmp_path / "rec", lambda k: f"img_{k:06d}.png", [k for k in range(N_FRAMES) if k != 150])
    frames = list(open_recording(rec).frames)
    assert len(frames) == N_FRAMES
    lost = [f.index for f in frames if not f.ok]
    assert lost == [150] and frames[150].dropped and "dropped" in frames[150].error
    t_true = np.array(truth["frames"]["t_s"])
    np.testing.assert_allclose([f.t_s for f in frames], t_true, rtol=0, atol=1e-12)
    assert np.array_equal(frames[151].image, _original(src, 151))


@pytest.mark.parametrize("pattern", ["img{k}.png", "{k}.png"])
def test_unpadded_names_are_in_numeric_order(synth, tmp_path, pattern: str) -> None:
    # img1.png ... img299.png used to be sorted as text (img10 before img2); 0.png ... 299.png crashed
    src, truth = synth
    rec = _copy(src, tmp_path / "rec", lambda k: pattern.format(k=k))
    frames = list(open_recording(rec).frames)
    assert [f.index for f in frames] == list(range(N_FRAMES))
    for k in (2, 10, 99, 100, 299):
        assert np.array_equal(frames[k].image, _original(src, k)), k
    np.testing.assert_allclose([f.t_s for f in frames], truth["frames"]["t_s"], rtol=0, atol=1e-12)


def test_missing_first_frame_keeps_the_time_origin_and_warns(synth, tmp_path, caplog) -> None:
    # Frame 0 deleted: frame k stays at t0_s + k/fps (used to shift every time by 1 ms, silently),
    # a warning says frame 0 is missing, and DIC measures from frame 1, the first frame present.
    src, truth = synth
    rec = _copy(src, tmp_path / "rec", keep=range(1, 80))
    with caplog.at_level(logging.WARNING):
        seq = open_recording(rec).frames
    assert seq.first_index == 1 and len(seq) == 79
    assert re.search(r"frame 0 is missing.*000001.png, is frame 1.*measured from frame 1", caplog.text)
    out = tmp_path / "track"
    assert main(["track", str(rec), "--out", str(out), "--no-progress"]) == 0
    with (out / "dic.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    t_true = np.array(truth["frames"]["t_s"])
    assert [int(r["frame"]) for r in rows] == list(range(1, 80))
    np.testing.assert_allclose([float(r["t_s"]) for r in rows], t_true[1:80], rtol=0, atol=1e-9)
    # displacement since frame 1: the synthetic rig's DIC error is far below 0.01 mm (0.17 px at 0.06 mm/px)
    ball = np.array(truth["frames"]["ball_mm"])
    structure = np.array(truth["frames"]["structure_mm"])
    np.testing.assert_allclose([float(r["ball_mm"]) for r in rows], ball[1:80] - ball[1], atol=0.01)
    np.testing.assert_allclose([float(r["structure_mm"]) for r in rows], structure[1:80] - structure[1], atol=0.01)


@pytest.mark.parametrize("names,problem", [
    (["a.png", "b.png", "c.png"], r"frame name a.png holds no frame number"),
    (["cam1_f0.png", "cam2_f1.png", "cam3_f2.png"], r"two numbers change across the frame names"),
    (["img_0.png", "img_1.png", "frame_2.png"], r"img_0.png and frame_2.png differ in more than one number"),
    (["00.png", "01.png", "1.png"], r"01.png and 1.png both carry frame number 1"),
    ([f"t{1000 * k}.png" for k in range(12)], r"frame numbers run from 0 to 11000 but only 12 files exist"),
])
def test_ambiguous_names_are_refused_saying_how_to_name(synth, tmp_path, capsys, names, problem) -> None:
    src, _ = synth
    rec = _copy(src, tmp_path / "rec", keep=[])
    for k, name in enumerate(names):
        shutil.copy(src / "frames" / f"{k:06d}.png", rec / "frames" / name)
    with pytest.raises(FrameError, match=problem):
        open_recording(rec)
    assert main(["info", str(rec)]) == 2
    err = capsys.readouterr().err.strip()
    assert RULE in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_one_frame_of_another_size_is_lost_and_analysis_goes_on(synth, tmp_path, caplog) -> None:
    # Same path as a corrupt frame: lost, reason naming file, its size and the expected size; results written.
    src, _ = synth
    rec = _copy(src, tmp_path / "rec")
    h, w = _original(src, 0).shape
    cv2.imwrite(str(rec / "frames" / "000137.png"), _original(src, 137)[:200, : w // 2])
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING):
        assert main(["analyze", str(rec), "--out", str(out), "--no-report", "--no-progress"]) == 0
    assert re.search(rf"frame 137: \S*000137.png: frame size {w // 2}x200 px differs from the expected {w}x{h} px",
                     caplog.text)
    with (out / "dic.csv").open() as fh:
        lost = [int(r["frame"]) for r in csv.DictReader(fh) if r["lost"] == "1"]
    assert lost == [137]
    doc = json.loads((out / "results.json").read_text())
    assert doc["impacts"] and any("1 lost" in w for w in doc["warnings"])


def test_many_unreadable_frames_refuse_the_recording(synth, tmp_path, capsys) -> None:
    # 16 of 300 (> 5 %) unreadable: refused with one line, exit 2, no results
    src, _ = synth
    rec = _copy(src, tmp_path / "rec")
    for k in range(10, 26):
        (rec / "frames" / f"{k:06d}.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    out = tmp_path / "out"
    assert main(["analyze", str(rec), "--out", str(out), "--no-report", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "16 of 300 frames are unreadable (more than 5%)" in err and "000010.png" in err
    assert len(err.splitlines()) == 1 and not (out / "results.json").exists()
