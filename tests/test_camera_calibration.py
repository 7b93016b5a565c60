"""Camera calibration (lens distortion) in every path (issue 40, part 2): the camera_info YAML, rig.yaml's
``camera.calibration``, the undistortion of tracked positions, ``vibro calibrate`` and ``vibro synth --lens-k1``,
and the live tracker's CameraInfo."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import shared_runs
import yaml

from vibro_app.cli import main
from vibro_io.camera_calibration import (
    CameraCalibration,
    CameraInfoError,
    distort_px,
    load_camera_info,
    undistort_px,
    write_camera_info,
)
from vibro_io.rig import load_rig
from vibro_model.errors import RecordingError

#: a 640 x 480 camera with a barrel lens, its principal point off the image centre
K_TRUE = np.array([[800.0, 0.0, 322.5], [0.0, 800.0, 236.0], [0.0, 0.0, 1.0]])
D_TRUE = [-0.2, 0.1, 0.0, 0.0, 0.0]


def _ros_info() -> dict:
    """A camera_info mapping as ROS camera_calibration writes it."""
    return {"image_width": 640, "image_height": 480, "camera_name": "cam1",
            "camera_matrix": {"rows": 3, "cols": 3, "data": K_TRUE.ravel().tolist()},
            "distortion_model": "plumb_bob",
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": [-0.2, 0.1, 0.001, -0.0005, 0.01]},
            "rectification_matrix": {"rows": 3, "cols": 3, "data": np.eye(3).ravel().tolist()},
            "projection_matrix": {"rows": 3, "cols": 4, "data": np.hstack([K_TRUE, np.zeros((3, 1))]).ravel().tolist()}}


# --------------------------------------------------------------------------------------------- the file
def test_write_then_load_gives_the_same_calibration(tmp_path: Path) -> None:
    calib = CameraCalibration(K_TRUE, [-0.21, 0.087, 1e-3, -2e-4, 0.013], 640, 480, camera_name="cam1")
    path = tmp_path / "camera_info.yaml"
    write_camera_info(path, calib, reprojection_error_px=0.1234)
    back = load_camera_info(path, image_size=(640, 480))
    np.testing.assert_array_equal(back.camera_matrix, calib.camera_matrix)  # repr floats: exact
    np.testing.assert_array_equal(back.dist_coeffs, calib.dist_coeffs)
    assert back.image_size == (640, 480) and back.camera_name == "cam1"
    assert back.reprojection_error_px == pytest.approx(0.1234)
    # what ROS's camera_info parser reads: the standard keys, shapes as ROS writes them
    data = yaml.safe_load(path.read_text())
    assert data["distortion_model"] == "plumb_bob"
    assert (data["distortion_coefficients"]["rows"], data["distortion_coefficients"]["cols"]) == (1, 5)
    assert len(data["projection_matrix"]["data"]) == 12 and len(data["rectification_matrix"]["data"]) == 9


def test_a_ros_file_and_an_opencv_file_read_alike(tmp_path: Path) -> None:
    ros = tmp_path / "ros.yaml"
    ros.write_text(yaml.safe_dump(_ros_info()))
    cv = tmp_path / "opencv.yaml"
    k = ", ".join(repr(float(v)) for v in K_TRUE.ravel())
    cv.write_text("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\n"
                  f"camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {k} ]\n"
                  "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n"
                  "   data: [ -0.2, 0.1, 1.0e-3, -5.0e-4, 1.0e-2 ]\n")
    a, b = load_camera_info(ros), load_camera_info(cv)
    assert a.same_as(b, rtol=0, atol=0)


def _refused(tmp_path: Path, data, image_size=None) -> str:
    path = tmp_path / "camera_info.yaml"
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    with pytest.raises(CameraInfoError) as err:
        load_camera_info(path, image_size)
    assert str(path) in str(err.value)
    return str(err.value)


def _without(key):
    def f(d):
        del d[key]
    return f


def _set(path: str, value):
    def f(d):
        *head, last = path.split(".")
        for h in head:
            d = d[h]
        d[last] = value
    return f


@pytest.mark.parametrize("change, key", [
    (_without("image_width"), "'image_width'"),
    (_set("image_height", -480), "'image_height'"),
    (_set("image_width", 640.5), "'image_width'"),
    (_without("camera_matrix"), "'camera_matrix'"),
    (_set("camera_matrix.rows", 2), "'camera_matrix.rows'"),
    (_set("camera_matrix.data", [800.0, 0, 320, 0, 800, 240, 0, 0]), "'camera_matrix.data'"),
    (_set("camera_matrix.data", [800.0, 0, 320, 0, float("nan"), 240, 0, 0, 1]), "'camera_matrix.data'"),
    (_set("camera_matrix.data", [0.0] * 9), "'camera_matrix.data'"),  # an uncalibrated driver's all-zero K
    (_set("camera_matrix.data", [800.0, 0, 320, 0, 800, 240, 0.1, 0, 1]), "'camera_matrix.data'"),
    (_set("camera_matrix", [800.0, 0, 320]), "'camera_matrix'"),
    (_without("distortion_model"), "'distortion_model'"),
    (_set("distortion_model", "equidistant"), "'distortion_model'"),
    (_without("distortion_coefficients"), "'distortion_coefficients'"),
    (_set("distortion_coefficients.cols", 4), "'distortion_coefficients.cols'"),
    (_set("distortion_coefficients.data", [-0.2, 0.1, 0.0, 0.0]), "'distortion_coefficients.data'"),
    (_set("distortion_coefficients.data", [-0.2, float("inf"), 0.0, 0.0, 0.0]), "'distortion_coefficients.data'"),
    (_set("distortion_coefficients.data", [-0.2, "a", 0.0, 0.0, 0.0]), "'distortion_coefficients.data'"),
    (_set("projection_matrix.data", [1.0] * 9), "'projection_matrix.data'"),
    (_set("rectification_matrix.cols", 4), "'rectification_matrix.cols'"),
])
def test_each_malformed_file_is_refused_naming_the_key(tmp_path: Path, change, key) -> None:
    data = _ros_info()
    change(data)
    assert key in _refused(tmp_path, data)


def test_unreadable_files_and_a_size_mismatch_are_refused(tmp_path: Path) -> None:
    assert "not valid YAML" in _refused(tmp_path, "image_width: [640\n")
    assert "mapping" in _refused(tmp_path, "- 1\n- 2\n")
    msg = _refused(tmp_path, _ros_info(), image_size=(160, 480))
    assert "'image_width'/'image_height'" in msg and "640x480" in msg and "160x480" in msg
    with pytest.raises(CameraInfoError, match="file not found"):
        load_camera_info(tmp_path / "none.yaml")


# --------------------------------------------------------------------------------------------- rig.yaml
def _recording_with(tmp_path: Path, tiny_recording: Path, calibration: str | None, info: dict | None) -> Path:
    rec = tmp_path / "rec"
    shutil.copytree(tiny_recording, rec)
    rig = yaml.safe_load((rec / "rig.yaml").read_text())
    if calibration is not None:
        rig["camera"]["calibration"] = calibration
    (rec / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    if info is not None:
        (rec / "camera_info.yaml").write_text(yaml.safe_dump(info))
    return rec


def _tiny_info(k1: float = -0.3) -> dict:
    info = _ros_info()
    info.update(image_width=96, image_height=128)
    info["camera_matrix"]["data"] = [100.0, 0, 47.5, 0, 100.0, 63.5, 0, 0, 1]
    info["distortion_coefficients"]["data"] = [k1, 0.0, 0.0, 0.0, 0.0]
    return info


def test_rig_yaml_names_its_calibration(tmp_path: Path, tiny_recording: Path) -> None:
    rec = _recording_with(tmp_path, tiny_recording, "camera_info.yaml", _tiny_info())
    rig = load_rig(rec / "rig.yaml")
    assert rig.camera.calibration == "camera_info.yaml"
    assert rig.to_dict()["camera"]["calibration"] == "camera_info.yaml"
    assert "calibration" not in load_rig(tiny_recording / "rig.yaml").to_dict()["camera"]  # absent: not written


@pytest.mark.parametrize("name, info, expect", [
    ("camera_info.yaml", None, "file not found"),
    ("/etc/camera_info.yaml", None, "absolute path"),
    ("../camera_info.yaml", None, "'..'"),
    ("camera_info.yaml", {**_tiny_info(), "distortion_model": "equidistant"}, "'distortion_model'"),
])
def test_a_calibration_rig_yaml_cannot_use_is_refused_naming_the_key(tmp_path: Path, tiny_recording: Path, name,
                                                                     info, expect) -> None:
    rec = _recording_with(tmp_path, tiny_recording, name, info)
    with pytest.raises(RecordingError) as err:
        load_rig(rec / "rig.yaml")
    assert "camera.calibration" in str(err.value) and expect in str(err.value) and "rig.yaml" in str(err.value)


def test_a_calibration_of_another_image_size_is_refused_before_tracking(tmp_path: Path, tiny_recording: Path,
                                                                        capsys) -> None:
    info = {**_tiny_info(), "image_width": 640, "image_height": 480}
    rec = _recording_with(tmp_path, tiny_recording, "camera_info.yaml", info)
    assert main(["track", str(rec), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "camera.calibration" in err and "640x480" in err and "96x128" in err


def test_a_bag_keeps_the_calibration_for_a_replay(tmp_path: Path, tiny_recording: Path) -> None:
    """The recorder keeps the file rig.yaml names in the bag's metadata; vibro replay writes it back beside the
    recorded rig.yaml, whose tracker then undistorts alike."""
    from vibro_io.camera_calibration import (
        BAG_CALIBRATION_KEY,
        calibration_custom_data,
        calibration_of_rig,
        write_recorded_calibration,
    )

    rec = _recording_with(tmp_path, tiny_recording, "camera_info.yaml", _tiny_info())
    custom = calibration_custom_data(rec / "rig.yaml")
    assert custom == {BAG_CALIBRATION_KEY: (rec / "camera_info.yaml").read_text()}
    assert calibration_custom_data(tiny_recording / "rig.yaml") == {}  # none named: nothing kept
    replay = tmp_path / "replay"
    replay.mkdir()
    rig_text = (rec / "rig.yaml").read_text()
    (replay / "rig.yaml").write_text(rig_text)
    assert write_recorded_calibration(replay, rig_text, custom) == replay / "camera_info.yaml"
    got = calibration_of_rig(load_rig(replay / "rig.yaml"))
    assert got.same_as(calibration_of_rig(load_rig(rec / "rig.yaml")), rtol=0, atol=0)
    assert write_recorded_calibration(replay, rig_text, {}) is None  # a bag recorded before the key existed


# --------------------------------------------------------------------------------------------- undistortion
def test_undistort_px_inverts_opencvs_projection_on_a_grid() -> None:
    import cv2

    calib = CameraCalibration(K_TRUE, [-0.28, 0.11, 8e-4, -6e-4, -0.02], 640, 480)
    xs, ys = np.meshgrid(np.linspace(0, 639, 33), np.linspace(0, 479, 25))
    ideal = np.stack([(xs.ravel() - K_TRUE[0, 2]) / K_TRUE[0, 0], (ys.ravel() - K_TRUE[1, 2]) / K_TRUE[1, 1],
                      np.ones(xs.size)], axis=-1)
    seen, _ = cv2.projectPoints(ideal, np.zeros(3), np.zeros(3), K_TRUE, calib.dist_coeffs)
    seen = seen.reshape(-1, 2)
    # the lens moves the corners of this image by tens of pixels: the inverse must be far better than DIC's noise
    assert np.max(np.hypot(seen[:, 0] - xs.ravel(), seen[:, 1] - ys.ravel())) > 20
    ux, uy = undistort_px(calib, seen[:, 0].reshape(xs.shape), seen[:, 1].reshape(xs.shape))
    assert ux.shape == xs.shape
    assert np.max(np.hypot(ux - xs, uy - ys)) < 0.01
    dx, dy = distort_px(calib, xs, ys)  # the synthetic lens's forward model is OpenCV's
    assert np.max(np.hypot(dx.ravel() - seen[:, 0], dy.ravel() - seen[:, 1])) < 1e-9


def test_an_identity_lens_changes_no_tracked_row(tiny_recording: Path) -> None:
    """k = 0: the undistortion path runs and must give the rows without it (to rounding)."""
    from vibro_dic.tracker import DicTracker
    from vibro_io.recording import open_recording

    rec = open_recording(tiny_recording)
    frames = [f for f in rec.frames if f.ok]
    plain, lens = (DicTracker.for_rig(frames[0].image, rec.rig) for _ in range(2))
    lens.use_calibration(CameraCalibration([[90.0, 0, 40.0], [0, 95.0, 70.0], [0, 0, 1]], [0.0] * 5, 96, 128))
    for f in frames:
        a, b = plain.track(f), lens.track(f)
        assert b.ball_mm == pytest.approx(a.ball_mm, abs=1e-9) and b.structure_mm == pytest.approx(a.structure_mm,
                                                                                                   abs=1e-9)
    assert plain.calibration is None and lens.calibration is not None


# --------------------------------------------------------------------------------------------- vibro calibrate
BOARD = (9, 6)  # inner corners
SQUARE_MM = 12.0


def _board_images(folder: Path, n_poses: int = 10, seed: int = 1) -> list[Path]:
    """Checkerboards seen through the lens of K_TRUE, D_TRUE: each pixel (3 x 3 samples) undistorted, mapped to
    the board plane by the pose's homography, painted by the square it falls in; slight blur and noise."""
    import cv2

    calib = CameraCalibration(K_TRUE, D_TRUE, 640, 480)
    ss = 3
    off = (np.arange(ss) + 0.5) / ss - 0.5
    ys, xs = np.mgrid[0:480, 0:640].astype(float)
    sx = np.broadcast_to(xs[..., None, None] + off[None, None, None, :], (480, 640, ss, ss)).ravel()
    sy = np.broadcast_to(ys[..., None, None] + off[None, None, :, None], (480, 640, ss, ss)).ravel()
    ux, uy = undistort_px(calib, sx, sy)
    cols, rows = BOARD
    centre = np.array([(cols - 1) * SQUARE_MM / 2, (rows - 1) * SQUARE_MM / 2, 0.0])
    grid = [(0, 0), (-1, -1), (1, -1), (-1, 1), (1, 1), (0, -1), (0, 1), (-1, 0), (1, 0), (0, 0)]
    rng = np.random.default_rng(seed)
    paths = []
    for k in range(n_poses):
        gx, gy = grid[k % len(grid)]
        tilt = 0.0 if (gx, gy) == (0, 0) else 0.3
        rvec = np.array([tilt * (-1) ** k, tilt * (-1) ** (k // 2), 0.05 * k])
        rot, _ = cv2.Rodrigues(rvec)
        t = np.array([gx * 80.0, gy * 55.0, 330.0 if k == 9 else 400.0 + 20 * k]) - rot @ centre
        hom = np.linalg.inv(K_TRUE @ np.column_stack([rot[:, 0], rot[:, 1], t]))
        p = hom @ np.vstack([ux, uy, np.ones_like(ux)])
        bx, by = p[0] / p[2], p[1] / p[2]
        i, j = np.floor(bx / SQUARE_MM), np.floor(by / SQUARE_MM)
        squares = (i >= -1) & (i <= cols - 1) & (j >= -1) & (j <= rows - 1)
        paper = (bx >= -2 * SQUARE_MM) & (bx <= (cols + 1) * SQUARE_MM) & (by >= -2 * SQUARE_MM) & \
            (by <= (rows + 1) * SQUARE_MM)
        value = np.where(squares, np.where((i + j) % 2 == 0, 30.0, 220.0), np.where(paper, 220.0, 120.0))
        img = cv2.GaussianBlur(value.reshape(480, 640, ss * ss).mean(axis=2), (0, 0), 0.6)
        img = np.clip(np.rint(img + rng.normal(0.0, 1.0, img.shape)), 0, 255).astype(np.uint8)
        paths.append(folder / f"board_{k:02d}.png")
        cv2.imwrite(str(paths[-1]), img)
    return paths


@pytest.fixture(scope="module")
def boards(tmp_path_factory) -> list[Path]:
    return _board_images(tmp_path_factory.mktemp("boards"))


def test_vibro_calibrate_recovers_the_lens(boards: list[Path], tmp_path: Path, capsys) -> None:
    out = tmp_path / "camera_info.yaml"
    assert main(["calibrate", *map(str, boards), "--pattern", "9x6", "--square-mm", str(SQUARE_MM),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    calib = load_camera_info(out, image_size=(640, 480))
    k = calib.camera_matrix
    for got, want in ((k[0, 0], 800.0), (k[1, 1], 800.0), (k[0, 2], 322.5), (k[1, 2], 236.0)):
        assert got == pytest.approx(want, rel=0.01)
    assert calib.dist_coeffs[0] == pytest.approx(D_TRUE[0], rel=0.10)
    # corners refined to sub-pixel on a 1-gray-level-noise image: far below half a pixel
    assert calib.reprojection_error_px < 0.5
    assert f"RMS reprojection error {calib.reprojection_error_px:.4f} px" in printed
    # what DIC needs of it: the lens's local scale across the image relative to the principal point's (7.5 % at
    # the corners here), which the undistortion removes; recovered to a tenth of its variation, as k1 is
    def relative_scale(c: CameraCalibration, x, y):
        def scale(x, y):
            return (undistort_px(c, x, y + 1.0)[1] - undistort_px(c, x, y - 1.0)[1]) / 2.0
        return scale(x, y) / scale(c.camera_matrix[0, 2], c.camera_matrix[1, 2])

    xs, ys = np.meshgrid(np.linspace(20, 620, 13), np.linspace(20, 460, 9))
    want = relative_scale(CameraCalibration(K_TRUE, D_TRUE, 640, 480), xs, ys)
    got = relative_scale(calib, xs, ys)
    assert np.max(np.abs(got - want)) < 0.1 * (want.max() - want.min())


def test_vibro_calibrate_refuses_too_few_boards_naming_the_images(boards: list[Path], tmp_path: Path,
                                                                  capsys) -> None:
    import cv2

    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 120, np.uint8))
    out = tmp_path / "camera_info.yaml"
    assert main(["calibrate", *map(str, boards[:3]), str(blank), "--pattern", "9x6", "--square-mm", "12",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "found in 3 of 4 images" in err and "at least 5" in err and str(blank) in err
    assert not out.exists()
    assert main(["calibrate", str(blank), "--pattern", "9", "--square-mm", "12", "--out", str(out)]) == 2
    assert "--pattern" in capsys.readouterr().err


# --------------------------------------------------------------------------------------------- synth + analyze
LENS_K1 = shared_runs.LENS_K1  # a barrel lens: ~1.5 % less scale at the lower plate than at the image centre


def _dic(path: Path) -> dict[str, np.ndarray]:
    rows = list(csv.DictReader(path.open()))
    return {k: np.array([float(r[k]) for r in rows]) for k in ("ball_mm", "structure_mm")}


@pytest.fixture(scope="module")
def lens_run(tmp_path_factory) -> dict:
    """One recording seen through the lens, analysed with its calibration and (a copy without the key) without
    (tests/shared_runs.py: made once per test run, shared with tests/test_optics.py); and the same scene without a
    lens, tracked: its error against the truth is the DIC's own noise."""
    lens = shared_runs.lens_recordings(tmp_path_factory)
    base = tmp_path_factory.mktemp("lens")
    plain = base / "plain"
    assert main(["synth", "--out", str(plain), "--frames", str(shared_runs.LENS_FRAMES), "--seed",
                 str(shared_runs.LENS_SEED), "--no-accel", "--no-progress"]) == 0
    out = {name: (lens[case]["doc"], _dic(lens[case]["out"] / "dic.csv"))
           for name, case in (("rec", "calibrated"), ("bare", "forgotten"))}
    assert main(["track", str(plain), "--out", str(base / "plain_out"), "--no-progress"]) == 0
    out["plain"] = (None, _dic(base / "plain_out" / "dic.csv"))
    out["truth"] = lens["truth"]
    out["plain_truth"] = json.loads((base / "plain.truth.json").read_text())
    return out


def _rms_error(track: dict[str, np.ndarray], truth: dict, body: str) -> float:
    true = np.asarray(truth["frames"][body])
    err = track[body] - (true - true[0])
    return float(np.sqrt(np.nanmean(err ** 2)))


def test_synth_writes_the_lens_and_its_calibration(lens_run: dict) -> None:
    lens = lens_run["truth"]["lens"]
    assert lens["k1"] == LENS_K1 and lens["calibration_file"] == "camera_info.yaml"
    # the barrel lens: the scale at the plates about 1.5 % below the centre's
    assert 0.98 < lens["structure_roi_scale_ratio"] < 0.99
    # the same scene without a lens: same truth
    assert lens_run["plain_truth"]["frames"]["ball_mm"] == lens_run["truth"]["frames"]["ball_mm"]


def test_analysis_with_the_calibration_matches_the_truth_and_without_it_does_not(lens_run: dict) -> None:
    truth = lens_run["truth"]
    mm_per_px = truth["image"]["mm_per_px"]
    amp = truth["structure"]["amplitude_mm"]
    (cal, cal_dic), (bare, bare_dic) = lens_run["rec"], lens_run["bare"]
    err_cal = abs(cal["structure"]["amplitude_mm"] - amp)
    err_bare = abs(bare["structure"]["amplitude_mm"] - amp)
    # uncalibrated, the amplitude carries the lens's scale error at the plate (1 - ratio, ~1.3-1.5 %), give or
    # take the spread of the plate's positions about the ROI's centre row
    scale_error = 1.0 - truth["lens"]["structure_roi_scale_ratio"]
    assert 0.5 * scale_error * amp < err_bare < 1.5 * scale_error * amp, (err_bare, scale_error * amp)
    # calibrated: within DIC's sub-pixel bias (a few thousandths of a pixel for this speckle, 0.005 px here)
    assert err_cal < 0.005 * mm_per_px, err_cal
    assert err_bare > 20 * err_cal
    # frame by frame, the positions: calibrated as close to the truth as the same scene filmed without a lens
    # (the DIC's own noise, measured), uncalibrated several times further
    for body in ("ball_mm", "structure_mm"):
        noise = _rms_error(lens_run["plain"][1], lens_run["plain_truth"], body)
        got_cal, got_bare = _rms_error(cal_dic, truth, body), _rms_error(bare_dic, truth, body)
        assert got_cal < 1.5 * noise, (body, got_cal, noise)
        assert got_bare > 5 * got_cal, (body, got_bare, got_cal)


def test_a_plain_ball_tracked_by_its_outline_is_undistorted_too(tmp_path: Path) -> None:
    """The outline method: the circle is refitted through the undistorted edge points (a lens turns the ball's
    circle into an oval whose fitted centre is not the distorted centre: off by 3 k1 y R^2 / f^2, ~0.1 px here)."""
    rec = tmp_path / "rec"
    assert main(["synth", "--out", str(rec), "--frames", "300", "--seed", "4", "--ball-surface", "plain",
                 "--lens-k1", str(LENS_K1), "--no-accel", "--no-progress"]) == 0
    bare = tmp_path / "bare"
    shutil.copytree(rec, bare)
    rig = yaml.safe_load((bare / "rig.yaml").read_text())
    del rig["camera"]["calibration"]
    (bare / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    truth = json.loads((tmp_path / "rec.truth.json").read_text())
    errors = {}
    for name in ("rec", "bare"):
        assert main(["track", str(tmp_path / name), "--out", str(tmp_path / f"{name}_out"), "--no-progress"]) == 0
        errors[name] = _rms_error(_dic(tmp_path / f"{name}_out" / "dic.csv"), truth, "ball_mm")
    # calibrated: within a hundredth of a pixel (the synthetic lens resamples the plain ball's sharp edge, sigma
    # 0.58 px, near the sampling limit: ~0.005 px of it remains); uncalibrated: the lens's ~1 % scale error
    assert errors["rec"] < 0.01 * truth["image"]["mm_per_px"], errors
    assert errors["bare"] > 10 * errors["rec"], errors


def test_no_calibration_file_leaves_the_lens_uncorrected(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    assert main(["synth", "--out", str(rec), "--frames", "5", "--lens-k1", str(LENS_K1), "--no-calibration-file",
                 "--no-accel", "--no-progress"]) == 0
    assert not (rec / "camera_info.yaml").exists()
    assert "calibration" not in yaml.safe_load((rec / "rig.yaml").read_text())["camera"]
    truth = json.loads((tmp_path / "rec.truth.json").read_text())
    assert truth["lens"]["calibration_file"] is None and truth["lens"]["k1"] == LENS_K1


# --------------------------------------------------------------------------------------------- live
ORIGIN_NS = 1_764_000_000_000_000_000


def _tracker_node(rec: Path, *params: str):
    import rclpy

    from vibro_dic.dic_tracker_node import DicTrackerNode

    rclpy.init(args=["--ros-args", "-p", f"rig_file:={rec / 'rig.yaml'}", "-p", "readers:=[nobody_yet]",
                     "-p", f"time_origin_unix_ns:={ORIGIN_NS}", "-p", "live_camera:=true",
                     "-p", f"reference_image:={rec / 'frames' / '000000.png'}", *params])
    return DicTrackerNode()


def _camera_info_message(info: dict):
    from sensor_msgs.msg import CameraInfo

    return CameraInfo(width=info["image_width"], height=info["image_height"],
                      distortion_model=info["distortion_model"], d=info["distortion_coefficients"]["data"],
                      k=info["camera_matrix"]["data"])


def _publish_until(node, pub, msg, done, timeout_s: float = 10.0) -> None:
    """A driver publishing ``msg`` (as drivers do, with every image) while ``node`` spins, until ``done()``."""
    import time

    import rclpy

    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        pub.publish(msg)
        rclpy.spin_once(node, timeout_sec=0.05)
    assert done(), "no CameraInfo arrived"


def _images(rec: Path) -> dict:
    from vibro_dic.frame_source_node import image_message
    from vibro_io.recording import open_recording

    return {f.index: image_message(f, "camera", ORIGIN_NS) for f in open_recording(rec).frames if f.ok}


def test_live_tracker_takes_the_drivers_camera_info(tmp_path: Path, tiny_recording: Path, close_rclpy,
                                                    ros_domain) -> None:
    """rig.yaml names no calibration: the driver's CameraInfo (sensor QoS, /camera/camera_info beside
    /camera/image_raw) is used from its arrival; until then, with camera_info_required, images are answered lost
    and /diagnostics says why."""
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CameraInfo

    rec = _recording_with(tmp_path, tiny_recording, None, None)
    node = _tracker_node(rec, "-p", "camera_info_required:=true", "-r", "vibro/frames:=/camera/image_raw")
    close_rclpy.append(node)
    assert node.calibration.topic == "/camera/camera_info"
    images = _images(rec)
    node._on_image(images[0])  # before any calibration: lost, and said so
    (row,) = node._held
    assert row.lost and row.status.startswith("no camera calibration yet") and "/camera/camera_info" in row.status
    assert node.health.values["frames_before_camera_info"] == 1
    assert node.health.values["camera_calibration"].startswith("none yet")
    driver = rclpy.create_node("camera_driver")
    close_rclpy.append(driver)
    pub = driver.create_publisher(CameraInfo, "/camera/camera_info", qos_profile_sensor_data)
    info = _tiny_info()
    _publish_until(node, pub, _camera_info_message(info), lambda: node.tracker.calibration is not None)
    assert node.tracker.calibration.dist_coeffs[0] == info["distortion_coefficients"]["data"][0]
    assert node.health.values["camera_calibration"].startswith("/camera/camera_info: fx 100.00")
    node._on_image(images[2])
    row = node._held[-1]
    assert not row.lost and int(row.frame_index) == 2


def test_live_tracker_keeps_rig_yamls_calibration_and_warns_once(tmp_path: Path, tiny_recording: Path,
                                                                  close_rclpy, ros_domain) -> None:
    """rig.yaml names one; a driver latching another (reliable, transient local): warned about once, rig.yaml's
    stays."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo

    rec = _recording_with(tmp_path, tiny_recording, "camera_info.yaml", _tiny_info(k1=-0.3))
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    warnings = []
    node = _tracker_node(rec)
    close_rclpy.append(node)
    node.get_logger().warning = warnings.append
    assert node.tracker.calibration.dist_coeffs[0] == -0.3  # rig.yaml's, from the start
    driver = rclpy.create_node("camera_driver")
    close_rclpy.append(driver)
    pub = driver.create_publisher(CameraInfo, "vibro/camera_info", latched)
    _publish_until(node, pub, _camera_info_message(_tiny_info(k1=-0.1)), lambda: warnings)
    for _ in range(5):
        pub.publish(_camera_info_message(_tiny_info(k1=-0.1)))
        rclpy.spin_once(node, timeout_sec=0.05)
    (warning,) = [w for w in warnings if "camera_info" in w]
    assert "differs from rig.yaml's" in warning and "rig.yaml's is used" in warning
    assert node.tracker.calibration.dist_coeffs[0] == -0.3
    assert node.health.values["camera_calibration"].startswith("rig.yaml")
