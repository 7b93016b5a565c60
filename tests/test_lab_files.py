"""Lab files (#14 Inputs): Photron MRAW, Phantom CINE, NI TDMS read like frames/ and accel.csv.

One synthetic recording (200 frames, 8-bit PNG + accel.csv) is rewritten into each format with
its own library (or the documented minimal writers of tests/lab_writers.py where it cannot
write); `vibro analyze` must give the very same CORs, since the pixels and samples are the same.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from lab_writers import CineClock, write_cine, write_mraw, write_mraw12, write_tdms  # noqa: E402

from vibro_app.cli import main  # noqa: E402
from vibro_io.frames import FrameSequence, read_image  # noqa: E402
from vibro_io.recording import open_recording  # noqa: E402
from vibro_io.rig import CameraConfig, load_rig  # noqa: E402

FPS = 1000.0
DAQ_START = np.datetime64("2024-05-01T10:00:00.000000", "us")
TDMS_ACCEL = {"file": "accel.tdms", "group": "accel", "upper_channel": "upper_plate", "lower_channel": "lower_plate"}


def _variant(src: Path, dst: Path, *, accel: dict | None = None, camera: dict | None = None) -> Path:
    """A copy of recording ``src`` without frames/ (rig.yaml edited: accelerometers / camera keys replaced)."""
    dst.mkdir()
    rig = yaml.safe_load((src / "rig.yaml").read_text())
    if accel is not None:
        rig["accelerometers"] = accel
    else:
        shutil.copy(src / "accel.csv", dst / "accel.csv")
    if camera is not None:
        rig["camera"] = camera
    (dst / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    return dst


def _cors(out: Path) -> np.ndarray:
    return np.array([i["cor"] for i in json.loads((out / "results.json").read_text())["impacts"]])


def _analyze(rec: Path, out: Path) -> int:
    return main(["analyze", str(rec), "--out", str(out), "--no-progress", "--no-report"])


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    from vibro_sim.synth import SynthConfig, synthesize

    root = tmp_path_factory.mktemp("lab")
    png = root / "png"
    synthesize(png, SynthConfig(frames=200, seed=5, effects={"asymmetric_restitution": {}}), progress=False)
    images = np.stack([read_image(p) for p in sorted((png / "frames").iterdir())])
    csv = np.loadtxt(png / "accel.csv", delimiter=",", skiprows=1)
    assert images.dtype == np.uint8 and images.shape[0] == 200

    mraw = _variant(png, root / "mraw_tdms", accel=TDMS_ACCEL)
    write_mraw(images, mraw / "video.cih", 8, FPS)
    dt_s = float(np.median(np.diff(csv[:, 0])))
    write_tdms(mraw / "accel.tdms", csv[:, 1], csv[:, 2], dt_s, DAQ_START)

    cine = _variant(png, root / "cine")  # 16-bit storage (pycine's path), accel.csv kept
    write_cine(images.astype(np.uint16), cine / "video.cine", FPS, real_bpp=16)

    outs = {}
    for name, rec in (("png", png), ("mraw_tdms", mraw), ("cine", cine)):
        assert _analyze(rec, root / f"out_{name}") == 0, name
        outs[name] = root / f"out_{name}"
    return {"root": root, "png": png, "mraw": mraw, "cine": cine, "images": images, "csv": csv, "dt_s": dt_s,
            "outs": outs}


def test_analyze_gives_the_same_cors_from_mraw_tdms_and_cine(lab):
    ref = _cors(lab["outs"]["png"])
    assert ref.size >= 4
    for name in ("mraw_tdms", "cine"):
        got = _cors(lab["outs"][name])
        assert got.shape == ref.shape, name
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9, err_msg=name)


def test_tdms_samples_and_daq_time_base(lab):
    rec = open_recording(lab["mraw"])
    accel = rec.load_accel()
    csv = lab["csv"]
    np.testing.assert_array_equal(accel.upper_ms2, csv[:, 1])
    np.testing.assert_array_equal(accel.lower_ms2, csv[:, 2])
    # no camera wall-clock start: DAQ start = camera time 0, sample i at i * wf_increment (CSV rounds to 1e-7 s)
    np.testing.assert_allclose(accel.t_s, csv[:, 0], rtol=0, atol=1e-7)
    assert accel.t_s[1] - accel.t_s[0] == pytest.approx(lab["dt_s"], rel=1e-12)


def test_tdms_placed_on_the_camera_clock_by_wall_times(lab, tmp_path):
    from vibro_io.tdms import load_tdms_accel

    cfg = open_recording(lab["mraw"]).rig.accelerometers
    daq_unix_s = (DAQ_START - np.datetime64(0, "us")) / np.timedelta64(1, "s")
    camera = CameraConfig(FPS, t0_s=0.5, mm_per_px=0.06, start_time_unix_s=daq_unix_s - 0.25)
    accel = load_tdms_accel(lab["mraw"] / "accel.tdms", cfg, camera)
    # the DAQ started 0.25 s after frame 0, which is at camera time 0.5 s
    assert accel.t_s[0] == pytest.approx(0.75, abs=1e-9)


def test_mraw_and_cine_frames_equal_the_png_frames_and_publish_the_same(lab):
    from vibro_dic.dic_tracker_node import image_array
    from vibro_dic.frame_source_node import image_message

    images = lab["images"]
    for rec, dtype in ((lab["mraw"], np.uint8), (lab["cine"], np.uint16)):
        frames = open_recording(rec).frames
        assert len(frames) == 200 and frames.shape == images.shape[1:]
        for frame, ref in zip(frames, images[:5]):
            assert frame.ok and frame.image.dtype == dtype
            np.testing.assert_array_equal(frame.image, ref)
            assert frame.t_s == pytest.approx(frame.index / FPS)
            msg = image_message(frame, "camera")  # what frame_source publishes in the graph
            np.testing.assert_array_equal(image_array(msg), frame.image)


def test_12_and_16_bit_pixels_are_scaled_to_the_same_16_bit_range(lab, tmp_path):
    full16 = lab["images"][:4].astype(np.uint16) * 257  # a 16-bit scene spanning the full range
    low12 = full16 >> 4  # what a 12-bit camera records of it
    files = {
        "mraw16": write_mraw(full16, tmp_path / "m16" / "video.cih", 16, FPS),
        "mraw12_packed": write_mraw12(low12, tmp_path / "m12" / "video.cih", FPS),
        "mraw16_eff12_lower": write_mraw(low12, tmp_path / "m1612" / "video.cih", 16, FPS, effective_bits=12),
        "cine16": write_cine(full16, tmp_path / "c16.cine", FPS, real_bpp=16),
        "cine12": write_cine(low12, tmp_path / "c12.cine", FPS, real_bpp=12),
    }
    cam = CameraConfig(FPS, 0.0, 0.06)
    read = {k: np.stack([f.image for f in FrameSequence(p, cam)]) for k, p in files.items()}
    for name, got in read.items():
        assert got.dtype == np.uint16, name
        want = full16 if name.endswith("16") else low12 << 4
        np.testing.assert_array_equal(got, want, err_msg=name)
        # 12-bit data differs from the 16-bit scene by less than one 12-bit step (16 counts), never by a scale
        assert np.abs(got.astype(int) - full16).max() < 16, name
    # 8-bit CINE (pycine cannot decode 8 bit: the minimal reader) and 8-bit MRAW keep uint8
    c8 = FrameSequence(write_cine(lab["images"][:3], tmp_path / "c8.cine", FPS, real_bpp=8), cam)
    np.testing.assert_array_equal(np.stack([f.image for f in c8]), lab["images"][:3])
    # a pixel above the header's declared depth is a corrupt frame, never silently wrapped
    bad = low12.copy()
    bad[2, 0, 0] = 5000
    seq = FrameSequence(write_mraw(bad, tmp_path / "bad" / "video.cih", 16, FPS, effective_bits=12), cam)
    errors = [f.error for f in seq if not f.ok]
    assert len(errors) == 1 and "frame 2" in errors[0] and "12-bit" in errors[0]


def test_header_fps_fills_rig_and_a_clash_is_refused(lab, tmp_path, capsys):
    cam = yaml.safe_load((lab["png"] / "rig.yaml").read_text())["camera"]
    no_fps = {"mm_per_px": cam["mm_per_px"]}  # fps, t0_s and start time from the CINE header
    rec = _variant(lab["png"], tmp_path / "fill", camera=no_fps)
    trigger = 1.7e9 + 0.125
    write_cine(lab["images"][:3], rec / "video.cine", 2000.0, real_bpp=8,
               clock=CineClock(first_image_no=-40, trigger_unix_s=trigger))
    rig = load_rig(rec / "rig.yaml")
    assert rig.camera.fps == 2000.0
    assert rig.camera.t0_s == pytest.approx(-40 / 2000.0)
    assert rig.camera.start_time_unix_s == pytest.approx(trigger - 0.02, abs=1e-6)
    assert [f.t_s for f in open_recording(rec).frames] == pytest.approx([-0.02, -0.0195, -0.019])

    clash = _variant(lab["png"], tmp_path / "clash", camera=dict(cam, fps=1000.0))
    write_cine(lab["images"][:3], clash / "video.cine", 2000.0, real_bpp=8)
    assert _analyze(clash, tmp_path / "out") == 2
    err = capsys.readouterr().err
    assert "camera.fps" in err and "1000" in err and "2000" in err and "video.cine" in err
    assert "Traceback" not in err and not (tmp_path / "out" / "results.json").exists()


def _truncate(path: Path, keep_bytes: int) -> None:
    with path.open("r+b") as f:
        f.truncate(keep_bytes)


def test_corrupt_or_truncated_files_give_one_clear_error(lab, tmp_path, capsys):
    images = lab["images"]
    frame_bytes = images[0].size
    cases = {}
    rec = _variant(lab["png"], tmp_path / "mraw_cut")
    write_mraw(images[:20], rec / "video.cih", 8, FPS)
    _truncate(rec / "video.mraw", 12 * frame_bytes + 100)
    cases["mraw_cut"] = (rec, ["video.mraw", "truncated", "frame 12"])

    rec = _variant(lab["png"], tmp_path / "cine_cut")
    write_cine(images[:20], rec / "video.cine", FPS, real_bpp=8)
    _truncate(rec / "video.cine", (rec / "video.cine").stat().st_size - 5 * frame_bytes)
    cases["cine_cut"] = (rec, ["video.cine", "truncated", "frame 15"])

    rec = _variant(lab["png"], tmp_path / "cine_garbage")
    (rec / "video.cine").write_bytes(b"not a cine" * 50)
    cases["cine_garbage"] = (rec, ["video.cine", "Phantom CINE"])

    rec = _variant(lab["png"], tmp_path / "cih_bad")
    write_mraw(images[:5], rec / "video.cih", 8, FPS)
    (rec / "video.cih").write_text("#Camera Information Header\nRecord Rate(fps) : 1000\n")
    cases["cih_bad"] = (rec, ["video.cih", "Total Frame"])

    rec = _variant(lab["png"], tmp_path / "tdms_cut", accel=TDMS_ACCEL)
    write_mraw(images[:20], rec / "video.cih", 8, FPS)
    shutil.copy(lab["mraw"] / "accel.tdms", rec / "accel.tdms")
    _truncate(rec / "accel.tdms", (rec / "accel.tdms").stat().st_size - 8 * 1000)
    n = lab["csv"].shape[0]
    cases["tdms_cut"] = (rec, ["accel.tdms", "accel/lower_plate", f"sample {n - 1000}", "truncated"])

    rec = _variant(lab["png"], tmp_path / "tdms_channel", accel=dict(TDMS_ACCEL, lower_channel="lower"))
    write_mraw(images[:20], rec / "video.cih", 8, FPS)
    shutil.copy(lab["mraw"] / "accel.tdms", rec / "accel.tdms")
    cases["tdms_channel"] = (rec, ["accel.tdms", "'accel/lower' not found", "lower_plate"])

    for name, (rec, words) in cases.items():
        assert _analyze(rec, tmp_path / f"out_{name}") == 2, name
        err = capsys.readouterr().err
        assert "Traceback" not in err, name
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1, (name, err)
        for word in words:
            assert word in lines[0], (name, word, lines[0])

    # the real command line: exit code 2, one line, no traceback
    res = subprocess.run([sys.executable, "-m", "vibro_app.cli", "analyze", str(cases["cine_cut"][0]),
                          "--out", str(tmp_path / "cli_out"), "--no-progress"], capture_output=True, text=True,
                         timeout=120, env=dict(os.environ))
    assert res.returncode == 2 and "Traceback" not in res.stderr and "frame 15" in res.stderr, res.stderr


def test_tdms_rate_and_clipping_are_checked(lab, tmp_path, caplog):
    from vibro_io.tdms import load_tdms_accel
    from vibro_model.errors import AccelError

    cfg = open_recording(lab["mraw"]).rig.accelerometers
    up, low = lab["csv"][:, 1].copy(), lab["csv"][:, 2]
    slow = write_tdms(tmp_path / "slow.tdms", up, low, 1e-3, DAQ_START)  # 1 kHz: slower than the camera
    with pytest.raises(AccelError, match=r"slow\.tdms: channel 'accel/upper_plate'.*1000 samples/s"):
        load_tdms_accel(slow, cfg, CameraConfig(FPS, 0.0, 0.06))
    peak = int(np.argmax(up))
    up[peak:peak + 5] = up[peak]  # a saturated amplifier: a flat top at the peak
    clipped = write_tdms(tmp_path / "clipped.tdms", up, low, lab["dt_s"], DAQ_START)
    with caplog.at_level("WARNING", logger="vibro_io.accel"):
        load_tdms_accel(clipped, cfg, CameraConfig(FPS, 0.0, 0.06))
    assert any("clipped.tdms: channel 'accel/upper_plate'" in r.message and f"sample {peak}" in r.message
               for r in caplog.records)


def test_long_mraw_streams_in_constant_memory(tmp_path):
    """20,000 frames (655 MB, a sparse file) iterated: the reader's peak memory must not grow with the file."""
    probe = r"""
import sys
from pathlib import Path
import pyMRAW  # its import (numba) happens before the baseline
from vibro_io.frames import FrameSequence
from vibro_io.rig import CameraConfig
def rss_kb():
    return int(next(l for l in open("/proc/self/status") if l.startswith("VmRSS:")).split()[1])
n, h, w = 20000, 128, 128
d = Path(sys.argv[1])
(d / "video.cih").write_text("Record Rate(fps) : 1000\nTotal Frame : %d\nImage Width : %d\nImage Height : %d\n"
    "Color Bit : 16\nFile Format : MRaw\nEffectiveBit Depth : 12\nEffectiveBit Side : Lower\n" % (n, w, h))
with open(d / "video.mraw", "wb") as f:
    f.truncate(n * h * w * 2)
seq = FrameSequence(d / "video.cih", CameraConfig(1000.0, 0.0, 0.05))
before = peak = rss_kb()
ok = 0
for fr in seq:
    ok += fr.ok
    if fr.index % 500 == 0:
        peak = max(peak, rss_kb())
print(ok, len(seq), before, max(peak, rss_kb()))
"""
    res = subprocess.run([sys.executable, "-c", probe, str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    ok, total, before_kb, after_kb = map(int, res.stdout.split())
    print(f"20000-frame MRAW (655 MB): RSS {before_kb / 1024:.0f} MB after opening, at most "
          f"{after_kb / 1024:.0f} MB while streaming")
    assert ok == total == 20000
    assert after_kb - before_kb < 64 * 1024  # 64 MB, a tenth of the file: frames are not kept
