"""``vibro init`` on synthetic recordings (vibro_sim.synth): ROIs the rig loader accepts, the scale against
the synth's true mm_per_px, and refusals (exit 2, one line) when the gap contradicts the ball or no ball."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from vibro_bringup.cli import main
from vibro_io.recording import open_recording

CASES = {  # several scales, ball sizes and ball positions (seed sets the phase, hence the ball's row)
    "default": dict(seed=2, mm_per_px=0.05, height_px=600),
    "big_ball": dict(seed=4, mm_per_px=0.075, ball_diameter_mm=8.0),
}


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp("init")
    out = {}
    for name, kw in CASES.items():
        rec = base / name
        truth = synthesize(rec, SynthConfig(frames=80, accel=False, **kw), progress=False)
        (rec / "rig.yaml").rename(base / f"{name}.true_rig.yaml")
        out[name] = (rec, truth, kw)
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_init_proposes_a_valid_rig_with_the_true_scale(recordings, name, capsys):
    rec, truth, kw = recordings[name]
    diameter = kw.get("ball_diameter_mm", 4.77)
    assert main(["init", str(rec), "--ball-diameter-mm", str(diameter), "--gap-mm", "16.6", "--fps", "1000",
                 "--overwrite"]) == 0
    opened = open_recording(rec)  # the rig loader accepts the proposal: ROIs inside the image, >= one subset
    true_scale = truth["image"]["mm_per_px"]
    assert opened.rig.camera.mm_per_px == pytest.approx(true_scale, rel=0.01)
    preview = cv2.imread(str(rec / "rig_preview.png"))
    assert preview is not None and preview.shape[0] == 2 * opened.frames.shape[0]


def test_init_refuses_a_gap_that_contradicts_the_ball(recordings, capsys):
    rec, _, kw = recordings["default"]
    # the true gap is 16.6 mm: 10 % more is far beyond what the edge and circle localisation allow
    code = main(["init", str(rec), "--ball-diameter-mm", "4.77", "--gap-mm", "18.26", "--fps", "1000",
                 "--out", str(rec.parent / "wrong.yaml")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "disagree" in err and len(err.splitlines()) == 1
    assert not (rec.parent / "wrong.yaml").exists()


def test_init_refuses_frames_without_a_ball(recordings, tmp_path, capsys):
    rec, _, _ = recordings["default"]
    frames = tmp_path / "noball" / "frames"
    frames.mkdir(parents=True)
    for k in range(3):
        img = cv2.imread(str(rec / "frames" / f"{k:06d}.png"), cv2.IMREAD_UNCHANGED)
        img[:, :] = np.median(img)  # a flat picture: no ball, no plates
        cv2.imwrite(str(frames / f"{k:06d}.png"), img)
    code = main(["init", str(frames.parent), "--ball-diameter-mm", "4.77", "--gap-mm", "16.6", "--fps", "1000"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "no ball found" in err
