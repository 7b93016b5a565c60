"""The instruments check each other (vibro_fit.cross_checks, vibro_fit.plausibility) through `vibro analyze`.

One short `vibro synth` recording (300 frames at 1000 fps, 22 Hz drive, constant COR 0.7, accelerometers in
m/s^2) is analysed once with DIC; each fault is that recording modified as a lab would get it wrong:
rig.yaml excitation.frequency_hz 50 for the 22 Hz drive; video.avi (FFV1) with one frame missing; accel.csv
written in g; the upper channel inverted; upper and lower columns swapped. The faults that leave the frames
alone reuse the clean run's dic.csv (``--track``), so each case costs an identification, not a DIC run.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from vibro_app.cli import main

G0 = 9.80665          # m/s^2 per g
FPS = 1000.0
DRIVE_HZ = 22.0
TRUE_COR = 0.7        # the synthetic rig's baseline restitution (no effect, no scatter)
#: COR accuracy on these recordings (tests/test_analyze_synth.py: MAE <= 0.005 at 2 gray levels of noise)
COR_TOL = 0.005
#: a calibrated accelerometer against the DIC acceleration: sensor calibration and image scale, a few %
AMPLITUDE_TOL = 0.10
#: the clock offset is known to ~0.1 ms (test_analyze_synth): 2 pi f 0.1 ms = 0.014 rad at 22 Hz; 0.05 rad bound
PHASE_TOL_RAD = 0.05
DROPPED = 150         # the frame whose image the video loses


def _analyze(rec: Path, out: Path, capsys, *extra: str) -> tuple[int, dict, str]:
    capsys.readouterr()
    rc = main(["analyze", str(rec), "--out", str(out), "--no-progress", "--no-report", *extra])
    err = capsys.readouterr().err
    doc = json.loads((out / "results.json").read_text()) if (out / "results.json").is_file() else {}
    return rc, doc, err


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    from vibro_sim.synth import SynthConfig, synthesize

    base = tmp_path_factory.mktemp("cross")
    synthesize(base / "rec", SynthConfig(frames=300, seed=3, frequency_hz=DRIVE_HZ), progress=False)
    assert main(["analyze", str(base / "rec"), "--out", str(base / "out"), "--no-progress", "--no-report"]) == 0
    return base, json.loads((base / "out" / "results.json").read_text())


def _copy(clean, name: str) -> Path:
    base, _ = clean
    dst = base / name
    shutil.copytree(base / "rec", dst, ignore=shutil.ignore_patterns("frames"))
    return dst


def _edit_rig(rec: Path, fn) -> None:
    rig = yaml.safe_load((rec / "rig.yaml").read_text())
    fn(rig)
    (rec / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))


def _rewrite_accel(rec: Path, upper: float, lower: float) -> None:
    data = np.loadtxt(rec / "accel.csv", delimiter=",", skiprows=1)
    data[:, 1] *= upper
    data[:, 2] *= lower
    np.savetxt(rec / "accel.csv", data, delimiter=",", header="time_s,upper_ms2,lower_ms2", comments="",
               fmt="%.9g")


def _findings(doc: dict, check: str) -> list[dict]:
    return [f for f in doc["consistency"]["findings"] if f["check"] == check]


def test_unmodified_recording_raises_no_finding(clean):
    # no false alarm: the clean recording passes every cross-check, and the checks' own numbers say why
    _, doc = clean
    cons = doc["consistency"]
    assert cons["refused"] is False and cons["findings"] == []
    assert not any(w.startswith("consistency:") for w in doc["warnings"])
    checks = cons["checks"]
    for ch in ("upper", "lower"):
        acc = checks["accelerometers"][ch]
        assert acc["ratio"] == pytest.approx(1.0, abs=AMPLITUDE_TOL)
        assert abs(acc["phase_rad"]) < PHASE_TOL_RAD
    plates = checks["plates"]
    assert plates["matched"] == len(doc["impacts"]) >= 10 and plates["disagree"] == 0
    # the largest phase step anywhere is noise: far below one frame period
    assert abs(checks["time_base"]["largest_step_s"]) < 0.05 / FPS
    assert doc["cor_summary"]["top"]["n"] + doc["cor_summary"]["bottom"]["n"] == len(doc["impacts"])


def test_wrong_excitation_frequency_is_refused_naming_the_key(clean, capsys):
    # item 2: rig.yaml says 50 Hz for a 22 Hz drive. The CORs measured against local structure fits seeded at
    # 50 Hz leave [0, 1]: refused (exit 2, one line) naming excitation.frequency_hz, not the gap or diameter
    base, _ = clean
    rec = _copy(clean, "f50")
    _edit_rig(rec, lambda r: r["excitation"].update(frequency_hz=50.0))
    rc, doc, err = _analyze(rec, base / "out_f50", capsys, "--track", str(base / "out" / "dic.csv"))
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vibro analyze: error: COR outside [0, 1]")
    assert "excitation.frequency_hz" in lines[0]
    assert doc["consistency"]["refused"] is True
    (finding,) = _findings(doc, "cor_outside_0_1")
    assert finding["severity"] == "refuse" and finding["keys"] == ["excitation.frequency_hz"]
    # the evidence: against the recording's own sine the same ball velocities give the true COR
    lo, hi = finding["evidence"]["cor_against_recording_sine_range"]
    assert TRUE_COR - COR_TOL <= lo <= hi <= TRUE_COR + COR_TOL
    assert finding["evidence"]["structure_frequency_hz"] == pytest.approx(DRIVE_HZ, abs=0.01)
    # the COR table is withheld; no statement blames a neighbouring key
    assert doc["impacts"] == []
    assert doc["cor_summary"]["top"]["n"] == doc["cor_summary"]["bottom"]["n"] == 0
    blamed = {k for r in doc["rig_consistency"] for k in r["keys"]}
    assert blamed == {"excitation.frequency_hz"}
    assert not any("gap - diameter likely" in w or w.startswith("measured free play") for w in doc["warnings"])


def _write_video(frames_dir: Path, path: Path, drop: int | None) -> int:
    import cv2

    files = sorted(frames_dir.iterdir())
    first = cv2.imread(str(files[0]), cv2.IMREAD_GRAYSCALE)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), FPS, (first.shape[1], first.shape[0]),
                             isColor=False)
    n = 0
    for k, f in enumerate(files):
        if k != drop:
            writer.write(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE))
            n += 1
    writer.release()
    return n


def test_video_missing_a_frame_is_refused_at_that_frame(clean, capsys):
    # item 3: video.avi (FFV1) without frame 150: 299 frames read, every later frame's time one period early.
    # The structure's phase steps by one frame period there: refused naming the frame. The same video with
    # every frame passes (no false alarm on the video path).
    base, _ = clean
    whole = _copy(clean, "video_whole")
    assert _write_video(base / "rec" / "frames", whole / "video.avi", None) == 300
    rc, doc, err = _analyze(whole, base / "out_video_whole", capsys)
    assert rc == 0, err
    assert doc["consistency"]["findings"] == []

    cut = _copy(clean, "video_cut")
    assert _write_video(base / "rec" / "frames", cut / "video.avi", DROPPED) == 299
    rc, doc, err = _analyze(cut, base / "out_video_cut", capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and f"frame {DROPPED}" in lines[0] and "video.avi" in lines[0]
    (finding,) = _findings(doc, "time_base_step")
    assert finding["frame"] == DROPPED and finding["evidence"]["kind"] == "lost_frame"
    # one frame period, to the linearisation's bias (second order in the phase step: w tau / 2) and the noise
    ev = finding["evidence"]
    bias = 2 * math.pi * DRIVE_HZ / FPS / 2
    assert ev["step_frames"] == pytest.approx(1.0, abs=bias + 5 * ev["step_std_s"] * FPS)
    assert doc["impacts"] == []


def test_accelerometers_in_g_are_named_and_unit_g_clears_it(clean, capsys):
    # item 4, units: accel.csv in g with no accelerometers.unit: the drive tone is 1/9.81 of the DIC acceleration
    base, _ = clean
    rec = _copy(clean, "in_g")
    _rewrite_accel(rec, 1.0 / G0, 1.0 / G0)
    rc, doc, err = _analyze(rec, base / "out_in_g", capsys, "--track", str(base / "out" / "dic.csv"))
    assert rc == 0
    found = _findings(doc, "accel_unit")
    assert sorted(f["evidence"]["channel"] for f in found) == ["lower", "upper"]
    for f in found:
        assert f["keys"] == ["accelerometers.unit"] and f["evidence"]["likely_unit"] == "g"
        assert f["evidence"]["ratio"] * G0 == pytest.approx(1.0, abs=AMPLITUDE_TOL)
    assert "accelerometers.unit: g" in err
    _edit_rig(rec, lambda r: r["accelerometers"].update(unit="g"))
    rc, doc, err = _analyze(rec, base / "out_in_g_fixed", capsys, "--track", str(base / "out" / "dic.csv"))
    assert rc == 0 and doc["consistency"]["findings"] == []


def test_inverted_channel_is_named(clean, capsys):
    # item 4, polarity: the upper channel's sign reversed: its drive tone is half a turn from the DIC acceleration
    base, _ = clean
    rec = _copy(clean, "inverted")
    _rewrite_accel(rec, -1.0, 1.0)
    rc, doc, err = _analyze(rec, base / "out_inverted", capsys, "--track", str(base / "out" / "dic.csv"))
    assert rc == 0
    (f,) = _findings(doc, "accel_polarity")
    assert f["evidence"]["channel"] == "upper" and f["keys"] == ["accelerometers.upper_column"]
    assert abs(abs(f["evidence"]["phase_rad"]) - math.pi) < PHASE_TOL_RAD
    # the inverted channel does not make the drive vanish from the DAQ clock (no false camera.fps statement)
    assert doc["rig_consistency"] == []


def test_swapped_channels_are_named(clean, capsys):
    # item 4, plates: upper and lower columns exchanged in rig.yaml: every impact's strongest channel is the
    # other plate's
    base, clean_doc = clean
    rec = _copy(clean, "swapped")
    _edit_rig(rec, lambda r: r["accelerometers"].update(upper_column="lower_ms2", lower_column="upper_ms2"))
    rc, doc, err = _analyze(rec, base / "out_swapped", capsys, "--track", str(base / "out" / "dic.csv"))
    assert rc == 0
    (f,) = _findings(doc, "accel_channels_swapped")
    assert f["keys"] == ["accelerometers.upper_column", "accelerometers.lower_column"]
    ev = f["evidence"]
    assert ev["disagree"] == ev["matched"] == len(clean_doc["impacts"]) and ev["agree"] == 0
    assert "accelerometer channels swapped" in err
    # the DIC results do not depend on the channel names: the COR table is the clean run's (read back from
    # dic.csv, whose rounding moves a COR by far less than a tenth of its own uncertainty)
    assert len(doc["impacts"]) == len(clean_doc["impacts"])
    for got, ref in zip(doc["impacts"], clean_doc["impacts"]):
        assert got["plate"] == ref["plate"]
        assert got["cor"] == pytest.approx(ref["cor"], abs=0.1 * ref["cor_std"])


@pytest.mark.parametrize("lost_share, refused", [(0.6, True), (0.4, False)])
def test_a_track_whose_ball_is_lost_in_most_frames_is_refused_as_analyze_refuses_its_tracking(lost_share, refused):
    from vibro_fit.cross_checks import tracking_check
    from vibro_io.dictrack import DicTrack

    n = 200
    lost = np.arange(n) >= int((1 - lost_share) * n)       # lost from some frame on, as a ball that spun away
    ball = np.where(lost, np.nan, 0.1 * np.sin(np.arange(n) / 10.0))
    rot = np.where(lost, np.nan, np.radians(8.0) * np.arange(n) / n)
    track = DicTrack(frame=np.arange(n), t_s=np.arange(n) / 1000.0, ball_mm=ball, structure_mm=np.zeros(n),
                     ball_valid=np.where(lost, 0, 4), structure_valid=np.full(n, 24), ball_zncc=np.ones(n),
                     structure_zncc=np.ones(n), lost=lost, ball_rot_rad=rot)
    finding = tracking_check(track)
    assert (finding is not None) is refused
    if refused:
        first = int(np.flatnonzero(lost)[0])
        assert finding.refuses and finding.check == "tracking" and "dic.ball_roi" in finding.keys
        assert finding.message.startswith(f"tracking refused: ball lost in {lost.sum()} of {n} frames")
        assert f"first: {first}, {first + 1}" in finding.message and "it spins" in finding.message
