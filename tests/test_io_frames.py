"""Frame loading: the committed fixture, 16-bit TIFF, video, corrupt, dropped and mismatched frames."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from vibro_io.frames import FrameSequence, read_image
from vibro_io.recording import open_recording
from vibro_model.errors import FrameError, RecordingError


def test_fixture_frames_count_dtype_and_times(tiny_recording: Path) -> None:
    rec = open_recording(tiny_recording)
    frames = list(rec.frames)
    assert len(rec.frames) == len(frames) == 5
    assert rec.frames.shape == (128, 96)
    assert all(f.ok and f.image.dtype == np.uint8 and f.image.shape == (128, 96) for f in frames)
    # rig.yaml says t0_s = 0.25 and fps = 1000: frame k is at 0.25 + k/1000 exactly.
    np.testing.assert_allclose([f.t_s for f in frames], 0.25 + np.arange(5) / 1000.0, rtol=0, atol=1e-15)
    # the fixture's lower half moves down 2 px per frame: the pixels say so too
    assert np.array_equal(frames[3].image[70:100], frames[2].image[68:98])


def _copy(tiny: Path, dst: Path) -> Path:
    shutil.copytree(tiny, dst)
    return dst


def test_sixteen_bit_tiff_frames(tiny_recording: Path, tmp_path: Path) -> None:
    rec_dir = _copy(tiny_recording, tmp_path / "rec")
    for png in sorted((rec_dir / "frames").glob("*.png")):
        img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED).astype(np.uint16) * 257
        cv2.imwrite(str(png.with_suffix(".tif")), img)
        png.unlink()
    rec = open_recording(rec_dir)
    frames = list(rec.frames)
    assert rec.frames.dtype == np.uint16 and len(frames) == 5
    assert frames[0].image.max() > 255


def test_video_source(tiny_recording: Path, tmp_path: Path) -> None:
    rec_dir = _copy(tiny_recording, tmp_path / "rec")
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((rec_dir / "frames").glob("*.png"))]
    writer = cv2.VideoWriter(str(rec_dir / "video.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 1000.0, (96, 128), False)
    for img in images:
        writer.write(img)
    writer.release()
    shutil.rmtree(rec_dir / "frames")
    rec = open_recording(rec_dir)
    frames = list(rec.frames)
    assert len(frames) == 5 and frames[0].image.shape == (128, 96)
    # MJPG is lossy: the content must still match to within a few gray levels on average
    assert np.mean(np.abs(frames[2].image.astype(int) - images[2].astype(int))) < 6


def test_corrupt_frame_is_named_and_the_rest_still_streams(tiny_recording: Path, tmp_path: Path) -> None:
    rec_dir = _copy(tiny_recording, tmp_path / "rec")
    (rec_dir / "frames" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    frames = list(open_recording(rec_dir).frames)
    assert [f.ok for f in frames] == [True, True, False, True, True]
    assert "000002.png" in frames[2].error and "frame 2" in frames[2].error
    with pytest.raises(FrameError, match="000002.png: cannot decode"):
        read_image(rec_dir / "frames" / "000002.png")


def test_dropped_frame_leaves_a_visible_gap(tiny_recording: Path, tmp_path: Path) -> None:
    rec_dir = _copy(tiny_recording, tmp_path / "rec")
    (rec_dir / "frames" / "000003.png").unlink()
    seq = open_recording(rec_dir).frames
    frames = list(seq)
    assert len(seq) == 5 and not frames[3].ok and "dropped" in frames[3].error
    assert frames[4].t_s == pytest.approx(0.25 + 4e-3)  # times follow the frame number, not the file count


def test_frame_of_differing_size_is_unreadable_and_many_refuse(tiny_recording: Path, tmp_path: Path) -> None:
    # One frame of another size is lost like a corrupt one, its error naming file, size and expected size;
    # the other frames still stream. (It used to stop the whole recording.)
    rec_dir = _copy(tiny_recording, tmp_path / "rec")
    cv2.imwrite(str(rec_dir / "frames" / "000004.png"), np.zeros((100, 96), np.uint8))
    frames = list(open_recording(rec_dir).frames)
    assert [f.ok for f in frames] == [True, True, True, True, False]
    assert re.search(r"frame 4: .*000004.png: frame size 96x100 px differs from the expected 96x128 px",
                     frames[4].error)
    # a second unreadable frame of five (40 % > 5 %) refuses the recording
    (rec_dir / "frames" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    with pytest.raises(FrameError, match=r"2 of 5 frames are unreadable \(more than 5%\); the recording is refused"):
        list(open_recording(rec_dir).frames)


def test_missing_frames_and_not_a_directory(tmp_path: Path, tiny_recording: Path) -> None:
    with pytest.raises(RecordingError, match="not a recording directory"):
        open_recording(tmp_path / "nope")
    rec_dir = _copy(tiny_recording, tmp_path / "rec")
    shutil.rmtree(rec_dir / "frames")
    with pytest.raises(FrameError, match="no frames/ folder and no video.avi"):
        open_recording(rec_dir)
    (rec_dir / "frames").mkdir()
    with pytest.raises(FrameError, match="no .png/.tif/.tiff frame files"):
        FrameSequence(rec_dir / "frames", open_recording(tiny_recording).rig.camera)


def test_missing_accel_file_named_before_work(tiny_recording: Path, tmp_path: Path) -> None:
    rec_dir = _copy(tiny_recording, tmp_path / "rec")
    (rec_dir / "accel.csv").unlink()
    with pytest.raises(RecordingError, match="accelerometers.file.*accel.csv"):
        open_recording(rec_dir)
