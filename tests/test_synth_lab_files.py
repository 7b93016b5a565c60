"""Issue 38 item 5: ``vibro synth --lab-files`` writes a lab's files, and a lab's path through them works.

The recording folder holds what a lab's camera and DAQ give it: an 8-bit Photron MRAW (video.mraw + its
video.cih header) and an NI TDMS of the two accelerometers, no rig.yaml (the truth file beside it, as
always). The lab's path is then run as a lab runs it, each command a separate process that never sees the
truth: ``vibro info`` on the camera file, ``vibro init RUN --ball-diameter-mm D --gap-mm G`` (which finds the
TDMS beside the video and names its group and plate channels in rig.yaml), ``vibro info RUN``, ``vibro analyze
RUN --no-report``; results.json is scored against the truth.

Tolerances. The noise: 2 gray levels of read noise on a 160x480 px speckle gives DIC position noise of a
few um, so a flight of ~20 frames measures the ball's velocity at an impact to ~1e-4 m/s and the COR to
~1e-4 (the propagated ``cor_std`` of these recordings: 4e-5 to 1.5e-4; errors seen up to 2e-4). The scale
is init's own (within 0.5 % of the truth), but a COR is a ratio of velocities and does not depend on it.
The bound 0.002 per impact (as issue 13's) is > 10 noise sigmas: what it leaves room for is a bias of the
lab-file path (a frame misplaced in time, pixels altered, the DAQ's samples shifted), which moves a COR
by far more. An impact is matched to the true one nearest in time; impacts are ~20 ms apart and the
frame period is 1 ms, so a match within 1 ms is the same impact.

The frames the MRAW holds are compared pixel by pixel with the PNG frames the same configuration writes
(both lossless 8-bit, read back through vibro's own frame reader).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
FRAMES = 600
SEED = 7
SCATTER = "0.015"
BALL_DIAMETER_MM, GAP_MM = "4.77", "16.6"   # the synthetic rig's (SynthConfig defaults), as a lab knows them
TOL_COR = 0.002
TOL_T_S = 1e-3


def _vibro(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=300, env=dict(os.environ),
                          cwd=ROOT)


@pytest.fixture(scope="module")
def lab(tmp_path_factory) -> dict:
    """A 600-frame take written as lab files, then the lab's path: info, init, info, analyze."""
    base = tmp_path_factory.mktemp("lab_files")
    rec, out = base / "run1", base / "run1_out"
    p = _vibro("synth", "--out", str(rec), "--frames", str(FRAMES), "--seed", str(SEED), "--cor-scatter", SCATTER,
               "--lab-files", "--no-progress")
    assert p.returncode == 0, p.stderr
    listing = sorted(e.name for e in rec.iterdir())
    info_camera = _vibro("info", str(rec / "video.cih"), "--json")
    init = _vibro("init", str(rec), "--ball-diameter-mm", BALL_DIAMETER_MM, "--gap-mm", GAP_MM)
    assert init.returncode == 0, init.stderr
    truth = json.loads(Path(f"{rec}.truth.json").read_text())
    info_rec = _vibro("info", str(rec), "--json")
    analyze = _vibro("analyze", str(rec), "--out", str(out), "--no-report", "--no-progress")
    assert analyze.returncode == 0, analyze.stderr
    return {"rec": rec, "listing": listing, "truth": truth, "info_camera": info_camera, "init": init,
            "info_rec": info_rec, "results": json.loads((out / "results.json").read_text())}


def test_the_folder_holds_a_labs_files(lab) -> None:
    assert lab["listing"] == ["accel.tdms", "video.cih", "video.mraw"]  # no frames/, no accel.csv, no rig.yaml
    rec = lab["rec"]
    assert (rec / "video.mraw").stat().st_size == FRAMES * 160 * 480  # 8-bit, one byte a pixel, nothing else
    assert lab["truth"]["lab_files"]["accelerometers"]["file"] == "accel.tdms"
    from nptdms import TdmsFile

    with TdmsFile.open(str(rec / "accel.tdms")) as tdms:
        chans = tdms["accel"].channels()
        assert [c.name for c in chans] == ["upper_plate", "lower_plate"]
        for c in chans:
            assert c.properties["wf_increment"] == pytest.approx(1 / 50000.0)
            assert c.properties["unit_string"] == "m/s^2"
            assert "wf_start_time" in c.properties
            assert len(c) == c.properties["wf_samples"] >= 50 * (FRAMES - 1)


def test_vibro_info_reads_the_camera_file_and_the_recording(lab) -> None:
    assert lab["info_camera"].returncode == 0, lab["info_camera"].stderr
    cam = json.loads(lab["info_camera"].stdout)
    assert cam["kind"] == "Photron MRAW" and cam["frames"] == FRAMES and cam["fps"] == 1000.0
    assert cam["fps_source"] == "header" and cam["bit_depth"] == {"container": 8, "effective": 8}
    assert cam["noise_gray"]["sigma"] == pytest.approx(2.0, rel=0.1)  # the synth's read noise
    assert lab["info_rec"].returncode == 0, lab["info_rec"].stderr
    rec = json.loads(lab["info_rec"].stdout)
    assert rec["frames"] == FRAMES and rec["fps"] == 1000.0
    acc = rec["accelerometers"]
    assert acc["rate_hz"] == pytest.approx(50000.0) and acc["unit"] == "m/s^2"
    assert acc["overlap_s"] == pytest.approx((FRAMES - 1) / 1000.0, abs=1e-3)


def test_init_takes_the_frame_rate_from_the_header_and_the_scale_from_the_lengths(lab) -> None:
    rig = yaml.safe_load((lab["rec"] / "rig.yaml").read_text())
    assert rig["camera"]["fps"] == 1000.0
    assert rig["camera"]["mm_per_px"] == pytest.approx(lab["truth"]["image"]["mm_per_px"], rel=0.005)


def test_analyze_finds_every_impact_and_its_cor(lab) -> None:
    truth = lab["truth"]["impacts"]
    t_true = np.array([i["t"] for i in truth])
    cor_true = np.array([i["cor"] for i in truth])
    # impacts the camera window cuts (the first before the first flight, the last after the last) have no
    # COR: every true impact inside the filmed flights must be there
    r = lab["results"]
    found = r["impacts"]
    assert len(found) >= len(truth) - 2 and len(truth) >= 20
    matched = []
    for imp in found:
        j = int(np.argmin(np.abs(t_true - imp["t"])))
        assert abs(imp["t"] - t_true[j]) < TOL_T_S, (imp["t"], t_true[j])
        assert abs(imp["cor"] - cor_true[j]) <= TOL_COR, (imp["t"], imp["cor"], cor_true[j])
        matched.append(j)
    assert len(set(matched)) == len(found)
    inside = [j for j, t in enumerate(t_true) if r["flights"][0]["t_start"] - TOL_T_S <= t
              <= r["flights"][-1]["t_end"] + TOL_T_S]
    assert set(inside) <= set(matched)
    # the accelerometers (the TDMS) were read and matched the camera's impacts
    acc = r["accelerometers"]
    assert acc["n_impacts"] >= len(found) - 2
    assert abs(acc["clock_offset_s"]) < 1e-4


def _frames(source: Path) -> list[np.ndarray]:
    from vibro_io.frames import FrameSequence
    from vibro_io.rig import CameraConfig

    seq = FrameSequence(source, CameraConfig(fps=1000.0, t0_s=0.0, mm_per_px=1.0))
    out = []
    for frame in seq:
        assert frame.ok, frame.error
        out.append(frame.image)
    return out


def test_the_mraw_frames_are_the_rendered_ones_pixel_for_pixel(tmp_path) -> None:
    from vibro_sim.synth import SynthConfig
    from vibro_sim.synth.write import synthesize

    cfg = SynthConfig(frames=40, seed=SEED, cor_scatter=0.015)
    synthesize(tmp_path / "png", cfg, progress=False)
    synthesize(tmp_path / "lab", cfg, progress=False, lab_files=True)
    png, mraw = _frames(tmp_path / "png" / "frames"), _frames(tmp_path / "lab" / "video.cih")
    assert len(png) == len(mraw) == 40
    for k, (a, b) in enumerate(zip(png, mraw)):
        assert a.dtype == b.dtype == np.uint8
        assert np.array_equal(a, b), f"frame {k} differs"
    # the DAQ's samples too: the TDMS holds accel.csv's times and values (accel.csv's to its 6 significant
    # digits, the TDMS's as float64)
    from vibro_io.accel import load_accel
    from vibro_io.tdms import load_tdms_accel
    from vibro_sim.synth.lab_files import LAB_ACCEL
    from vibro_sim.synth.write import ACCEL_COLUMNS

    csv = load_accel(tmp_path / "png" / "accel.csv", ACCEL_COLUMNS)
    tdms = load_tdms_accel(tmp_path / "lab" / "accel.tdms", LAB_ACCEL)
    np.testing.assert_allclose(tdms.t_s, csv.t_s, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tdms.upper_ms2, csv.upper_ms2, rtol=5.1e-6, atol=1e-12)
    np.testing.assert_allclose(tdms.lower_ms2, csv.lower_ms2, rtol=5.1e-6, atol=1e-12)


def test_a_synth_stopped_while_writing_frames_leaves_no_camera_file(tmp_path) -> None:
    from vibro_sim.synth.lab_files import MrawWriter

    frame = np.zeros((8, 6), np.uint8)
    with pytest.raises(KeyboardInterrupt), MrawWriter(tmp_path, 10, 1000.0, 5e-4) as mraw:
        for _ in range(3):
            mraw.write(frame)
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_lab_files_refuse_deeper_pixels(tmp_path) -> None:
    p = _vibro("synth", "--out", str(tmp_path / "r"), "--frames", "10", "--lab-files", "--tiff16", "--no-progress")
    assert p.returncode != 0 and "8-bit MRAW" in p.stderr


def test_init_names_the_daq_file_it_found_beside_the_video(lab) -> None:
    """Typing only the ball's diameter and the gap, the lab's rig.yaml names the TDMS and its plate channels as
    the DAQ wrote them (the truth file's lab_files block), and init says so."""
    rig = yaml.safe_load((lab["rec"] / "rig.yaml").read_text())
    want = lab["truth"]["lab_files"]["accelerometers"]
    assert {k: rig["accelerometers"][k] for k in want} == want
    assert "accelerometers: accel.tdms" in lab["init"].stdout
