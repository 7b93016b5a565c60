"""Real camera files read as the instrument recorded them: time base, pixels, names, ``vibro info --json``.

Ground truth: ../shared/validation/lab_files (real Photron and Phantom files; what is known about each
is in its README, measured independently of vibro), and CINE files written here that reproduce the
faults no shared file shows (garbage display levels, a colour filter array, time stamps with a dropped
image). The CINE writer (tests/lab_writers.py) lays out the format's structures itself.
"""

from __future__ import annotations

import json
import shutil
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from lab_writers import CineClock, write_cine  # noqa: E402

from vibro_app.cli import main  # noqa: E402
from vibro_io.camera_files import open_camera_file  # noqa: E402
from vibro_io.frames import FrameSequence  # noqa: E402
from vibro_io.recording import open_recording  # noqa: E402
from vibro_io.rig import CameraConfig, load_rig  # noqa: E402
from vibro_model.errors import FrameError, RigError  # noqa: E402

LAB = Path(__file__).resolve().parents[1].parent / "shared" / "validation" / "lab_files"
TINY = Path(__file__).parent / "fixtures" / "tiny_recording"


def _info(path: Path, capsys) -> dict:
    assert main(["info", str(path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def _recording(tmp_path: Path, files: list[str], camera: dict, name: str = "rec", rename: dict | None = None) -> Path:
    """A recording of shared camera file(s) (copied in) with the tiny fixture's rig, camera keys replaced."""
    rec = tmp_path / name
    rec.mkdir()
    for f in files:
        shutil.copy(LAB / f, rec / (rename or {}).get(f, f))
    rig = yaml.safe_load((TINY / "rig.yaml").read_text())
    rig["camera"] = camera
    rig.pop("accelerometers")
    rig["dic"].update(ball_roi=[0, 0, 32, 32], structure_roi=[0, 0, 32, 32])
    (rec / "rig.yaml").write_text(yaml.safe_dump(rig))
    return rec


# ------------------------------------------------------------------------------------- time base


def _stamp_ticks(path: Path) -> np.ndarray:
    """The TIME64 stamps of a CINE as integer ticks of 2**-32 s, read here with struct alone (the block
    layout: setup at OffSetup, its Length, then tagged blocks of uint32 size, uint16 type, uint16 reserved)."""
    data = path.read_bytes()
    off_setup, off_offsets = struct.unpack_from("<I", data, 28)[0], struct.unpack_from("<I", data, 32)[0]
    count = struct.unpack_from("<I", data, 20)[0]
    offset = off_setup + struct.unpack_from("<H", data, off_setup + 142)[0]  # setup.Length: uint16 at byte 142
    while offset < off_offsets:
        size, kind = struct.unpack_from("<IH", data, offset)
        if kind == 1002:
            pairs = np.frombuffer(data, "<u4", 2 * count, offset + 8).reshape(count, 2).astype(np.int64)
            return pairs[:, 1] * 2 ** 32 + pairs[:, 0]
        offset += size
    raise AssertionError("no time block")


def test_cine_time_stamps_are_the_time_base_not_the_header_rate(capsys):
    """README: the header says 90000 frames/s, the images' own stamps are 111.1 us apart (every 10th frame saved).

    The README's 9000.65 images/s comes from stamps converted to float64 Unix seconds, which resolve 0.24 us
    only; the stamps' integer ticks (2**-32 s) give 111.0714 us: the rate is checked against those.
    """
    info = _info(LAB / "cine_781.cine", capsys)
    assert info["fps_source"] == "time stamps"
    spacing_s = float(np.median(np.diff(_stamp_ticks(LAB / "cine_781.cine")))) / 2 ** 32
    assert round(spacing_s * 1e6, 1) == 111.1  # the README's value, to its digits
    assert info["fps"] == pytest.approx(1 / spacing_s, rel=1e-6)
    assert info["record_fps"] == 90000
    assert any("90000" in n and "every 10th" in n for n in info["time_base_notes"])
    # Header: FirstImageNo -5417 at 90000/s puts frame 0 at -0.060 s; the stamps, 0.54 s earlier (the offset).
    assert -0.61 < info["t0_s"] < -0.59
    assert info["frames"] == 15 and info["duration_s"] == pytest.approx(15 * spacing_s, rel=1e-6)


def test_a_user_rate_matching_the_stamps_is_accepted_and_the_header_rate_refused(tmp_path):
    ok = _recording(tmp_path, ["cine_781.cine"], {"fps": 9000.0, "mm_per_px": 0.05}, "ok")
    assert load_rig(ok / "rig.yaml").camera.fps == 9000.0  # 1e-4 from the stamps: 0.001 frame over 15 frames
    wrong = _recording(tmp_path, ["cine_781.cine"], {"fps": 90000.0, "mm_per_px": 0.05}, "wrong")
    with pytest.raises(RigError, match="90000") as err:
        load_rig(wrong / "rig.yaml")
    assert "9003.2" in str(err.value) and "time stamps" in str(err.value)  # 1 / 111.0714 us


def test_frames_from_stamps_sit_at_their_stored_times_and_a_dropped_image_is_a_gap(tmp_path):
    rng = np.random.default_rng(3)
    images = rng.integers(0, 4096, size=(6, 8, 8), dtype=np.uint16)
    trigger, dt = 1.7e9, 1 / 2500.0
    slots = np.array([0, 1, 2, 4, 5, 6])  # the camera dropped the image of slot 3
    stamps = -0.01 + slots * dt + rng.normal(0, 2e-8, slots.size)  # s after the trigger; 20 ns clock jitter
    path = write_cine(images, tmp_path / "take.cine", 25000.0, real_bpp=12,
                      clock=CineClock(trigger_unix_s=trigger, time_stamps_s=stamps))
    header = open_camera_file(path).header
    assert header.fps == pytest.approx(2500.0, rel=1e-4)  # stamps stored to 2**-32 s, jitter 20 ns over 400 us
    assert header.t0_s == pytest.approx(-0.01, abs=1e-6)
    frames = list(FrameSequence(path, CameraConfig(fps=header.fps, t0_s=header.t0_s, mm_per_px=1.0)))
    assert [f.dropped for f in frames] == [False, False, False, True, False, False, False]
    ok = [f for f in frames if f.ok]
    assert [f.t_s for f in ok] == pytest.approx(list(stamps), abs=1e-7)  # 20 ns jitter: 5 sigma
    for frame, image in zip(ok, images):
        np.testing.assert_array_equal(frame.image >> 4, image)


def test_a_stamp_off_the_clock_makes_that_image_unreadable_not_misplaced(capsys):
    """data_small_cine: image 234's stamp lies 25 million s after image 233's (10 ms apart elsewhere)."""
    info = _info(LAB / "data_small_cine.cine", capsys)
    assert info["images"] == 235 and info["unreadable_images"] == [234] and info["frames"] == 234
    assert info["fps"] == pytest.approx(100.0, rel=1e-4) and info["fps_source"] == "time stamps"


def test_photron_save_step_spaces_the_saved_frames_when_the_take_can_hold_them(capsys):
    """data_showcase.cih: Save Step 100, Original Total Frame 15000, 75 frames: 7401 recorded frames fit."""
    info = _info(LAB / "data_showcase.cih", capsys)
    assert info["fps"] == pytest.approx(15000 / 100) and info["fps_source"] == "header save step"
    assert info["duration_s"] == pytest.approx(75 / 150)


def test_a_contradictory_photron_header_fixes_no_rate_and_rig_yaml_must(tmp_path, capsys):
    """beam.cihx: skipFrame 2500, but 4 frames 2500 apart need 7501 recorded frames; recordedFrame is 400."""
    info = _info(LAB / "beam.cihx", capsys)
    assert info["fps"] is None and sorted(info["fps_candidates"]) == [20, 50000]
    files = ["beam.cihx", "beam.mraw"]
    with pytest.raises(RigError, match="camera.fps") as err:
        load_rig(_recording(tmp_path, files, {"mm_per_px": 0.05}, "none") / "rig.yaml")
    assert "50000" in str(err.value) and "20" in str(err.value)
    assert load_rig(_recording(tmp_path, files, {"fps": 20, "mm_per_px": 0.05}, "slow") / "rig.yaml").camera.fps == 20
    with pytest.raises(RigError, match="1000"):
        load_rig(_recording(tmp_path, files, {"fps": 1000, "mm_per_px": 0.05}, "other") / "rig.yaml")


# ------------------------------------------------------------------------------------- pixels


def test_packed_10bit_cine_decodes_every_image():
    """README: pycine decodes all 235 frames of this packed 10-bit file; vibro gives the same images.

    pycine ends with a display stretch of its 12-bit values from [64, 4064] to [0, 4095]; vibro keeps the
    linearised values, so the comparison applies that stretch to vibro's image.
    """
    from pycine.raw import read_frames

    camera = open_camera_file(LAB / "data_small_cine.cine")
    assert camera.header.n_frames == 235
    images, _, bpp = read_frames(str(LAB / "data_small_cine.cine"))
    assert bpp == 12
    for k, reference in enumerate(images):
        image = camera.read(k) >> 4
        stretched = np.interp(image, [64, 4064], [0, 4095]).astype(np.uint16)
        np.testing.assert_array_equal(stretched, reference)
    assert k == 234


def test_garbage_display_levels_do_not_blank_the_frames(tmp_path):
    """An old CINE whose setup levels are meaningless: pycine's rescaling gives all-zero frames; vibro the raw data."""
    rng = np.random.default_rng(5)
    images = rng.integers(0, 4096, size=(3, 16, 16), dtype=np.uint16)
    path = write_cine(images, tmp_path / "old.cine", 1000.0, real_bpp=12, black_white=(65535, 65535))
    from pycine.file import read_header
    from pycine.raw import frame_reader

    through_pycine = next(frame_reader(str(path), read_header(str(path)), start_frame=1, count=1))
    assert through_pycine.max() == 0  # the fault: a constant frame
    camera = open_camera_file(path)
    for k in range(3):
        np.testing.assert_array_equal(camera.read(k) >> 4, images[k])


def test_values_beyond_the_declared_depth_and_colour_files_are_refused_by_name(tmp_path):
    too_deep = np.full((2, 8, 8), 5000, dtype=np.uint16)  # 5000 > 4095: not 12-bit data
    with pytest.raises(FrameError, match="12-bit"):
        open_camera_file(write_cine(too_deep, tmp_path / "deep.cine", 1000.0, real_bpp=12)).read(0)
    grey = np.zeros((2, 8, 8), dtype=np.uint16)
    with pytest.raises(FrameError, match="colour"):
        open_camera_file(write_cine(grey, tmp_path / "bayer.cine", 1000.0, real_bpp=12, cfa=3))


# ------------------------------------------------------------------------------------- names, info


def test_camera_files_under_their_own_names_and_any_case(tmp_path, capsys):
    own = _recording(tmp_path, ["ball_12bit.cihx", "ball_12bit.mraw"], {"mm_per_px": 0.05}, "own")
    rec = open_recording(own)
    assert len(rec.frames) == 15 and rec.rig.camera.fps == 30000
    upper = _recording(tmp_path, ["ball_12bit.cihx", "ball_12bit.mraw"], {"mm_per_px": 0.05}, "upper",
                       rename={"ball_12bit.cihx": "video.CIHX", "ball_12bit.mraw": "video.MRAW"})
    assert len(open_recording(upper).frames) == 15
    two = _recording(tmp_path, ["ball_12bit.cihx", "ball_12bit.mraw", "cine_781.cine"], {"mm_per_px": 0.05}, "two")
    assert main(["info", str(two)]) == 2
    err = capsys.readouterr().err
    assert "rename" in err and "ball_12bit.cihx" in err and "cine_781.cine" in err and "camera.fps" not in err


def test_info_json_of_each_shared_file_gives_its_readme_values(capsys):
    ball = _info(LAB / "ball_12bit.cihx", capsys)
    assert (ball["frames"], ball["width_px"], ball["height_px"]) == (15, 384, 384)
    assert ball["fps"] == 30000 and ball["fps_source"] == "header"
    assert ball["bit_depth"] == {"container": 16, "effective": 12}
    assert ball["frame0_gray"]["max"] == 4095 and ball["frame0_gray"]["saturated_share"] > 0.5  # "most of the image"
    beam = _info(LAB / "beam.cihx", capsys)
    assert (beam["frames"], beam["width_px"], beam["height_px"]) == (4, 1024, 80)
    assert beam["bit_depth"] == {"container": 16, "effective": 12}
    show = _info(LAB / "data_showcase.cih", capsys)
    assert (show["frames"], show["width_px"], show["height_px"]) == (75, 640, 40)
    assert show["bit_depth"] == {"container": 8, "effective": 8}
    small = _info(LAB / "data_small_cine.cine", capsys)
    assert (small["images"], small["width_px"], small["height_px"]) == (235, 256, 32)
    cine = _info(LAB / "cine_781.cine", capsys)
    assert (cine["frames"], cine["width_px"], cine["height_px"]) == (15, 256, 256)
    assert cine["bit_depth"]["effective"] == 12  # RealBPP 12 in a 16-bit container
    for info in (ball, beam, show, small, cine):  # real sensors: never noise-free, never below quantization
        assert info["noise_gray"]["sigma"] >= 1 / np.sqrt(12)
    # ball_12bit: the backlight is left out as saturated, so the noise comes from the rest of the image
    assert "clipped pixel left out" in ball["noise_gray"]["method"]


def test_human_info_shows_the_time_origin_and_enough_digits(capsys):
    assert main(["info", str(LAB / "beam.cihx")]) == 0
    out = capsys.readouterr().out
    assert "0.0005 s" not in out and "contradicts" in out
    assert main(["info", str(LAB / "ball_12bit.cihx")]) == 0
    out = capsys.readouterr().out
    assert "0.0005 s" in out and "0.00173333" in out  # 15 frames at 30 kfps; Start Frame 52 / 30000
