"""Frame-by-frame tracking: large motions with reversals, dropped/garbage frames, ROI leaving
the image, outlier rejection, bad input (vibro_dic.tracker)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vibro_dic.speckle import RigScene, scene_rig_mapping
from vibro_dic.tracker import DicTracker
from vibro_io.frames import Frame
from vibro_io.rig import DicConfig, Roi, parse_rig
from vibro_model.errors import FrameError, RecordingError

MM_PER_PX = 0.05


@pytest.fixture(scope="module")
def scene() -> RigScene:
    return RigScene((160, 480), seed=7)


def _tracker(scene: RigScene, ref: np.ndarray, **kw) -> DicTracker:
    rig = parse_rig(scene_rig_mapping(scene, mm_per_px=MM_PER_PX), "test")
    return DicTracker(ref, rig.dic, MM_PER_PX, **kw)


def _triangle(n: int, amplitude: float, period: int) -> np.ndarray:
    """Ball-like motion: constant speed with instant reversals (impacts), amplitude in px, 0 at frame 0."""
    phase = ((np.arange(n) + period / 4) % period) / period
    return amplitude * (4.0 * np.abs(phase - 0.5) - 1.0)


def test_tracks_tens_of_px_per_frame_through_reversals() -> None:
    # portrait 480 x 160 px frame (the rig's vertical motion axis), ball ROI at rows 210..270
    tall = RigScene((480, 160), split_col=60, ball_x_px=110.0, ball_y0_px=240.0, ball_radius_px=47.0, seed=8)
    n = 60
    # 40 px/frame with instant reversals: the velocity jumps by 80 px/frame at each "impact",
    # far beyond the +-4 px search window around the prediction
    ball = _triangle(n, 100.0, 10) + 0.37
    structure = 20.0 * np.sin(2 * np.pi * 22.0 * np.arange(n) / 1000.0)
    rng = np.random.default_rng(3)
    frames = [tall.frame(b, s, noise_sigma=2.0, rng=rng) for b, s in zip(ball, structure)]
    tr = _tracker(tall, frames[0])
    rows = [tr.track(Frame(k, k / 1000.0, img, "mem")) for k, img in enumerate(frames)]
    assert not any(r.lost for r in rows)
    got_b = np.array([r.ball_mm for r in rows]) / MM_PER_PX
    got_s = np.array([r.structure_mm for r in rows]) / MM_PER_PX
    # exact band-limited shifts + sigma = 2 noise: per-mesh error ~0.003 px (see the accuracy
    # tests); 0.01 px is the accuracy goal, so a search or sign error would show at once
    assert np.sqrt(np.mean((got_b - (ball - ball[0])) ** 2)) <= 0.01
    assert np.sqrt(np.mean((got_s - (structure - structure[0])) ** 2)) <= 0.01
    assert all(r.ball_valid >= 14 and r.structure_valid >= 22 for r in rows)
    assert all(r.ball_zncc > 0.95 for r in rows)
    assert [r.frame for r in rows] == list(range(n))
    assert rows[5].t_s == pytest.approx(0.005)


def test_sixteen_bit_frames_track_like_eight_bit(scene: RigScene) -> None:
    rng = np.random.default_rng(4)
    ref = scene.frame(0.0, 0.0, noise_sigma=2.0, rng=rng)
    img = scene.frame(1.37, -0.42, noise_sigma=2.0, rng=rng)
    a = _tracker(scene, ref).track_image(1, 0.001, img)
    b = _tracker(scene, ref.astype(np.uint16) * 257).track_image(1, 0.001, img.astype(np.uint16) * 257)
    # ZNCC/ZNSSD are invariant to gain: the same images scaled to 16 bit give the same answer
    assert b.ball_mm == pytest.approx(a.ball_mm, abs=1e-4 * MM_PER_PX)
    assert b.structure_mm == pytest.approx(a.structure_mm, abs=1e-4 * MM_PER_PX)
    assert a.ball_mm / MM_PER_PX == pytest.approx(1.37, abs=0.01)


def test_dropped_and_garbage_frames_are_lost_not_extrapolated(scene: RigScene) -> None:
    n = 30
    ball = 3.0 * np.arange(n) / n * 10  # 1 px/frame upwards
    rng = np.random.default_rng(5)
    frames = [scene.frame(b, 0.0, noise_sigma=2.0, rng=rng) for b in ball]
    frames[10] = None  # dropped frame
    frames[11] = None
    frames[20] = rng.integers(0, 256, size=(160, 480), dtype=np.uint8)  # corrupt content
    tr = _tracker(scene, frames[0])
    rows = [tr.track(Frame(k, k / 1000.0, img, "mem", None if img is not None else "missing"))
            for k, img in enumerate(frames)]
    for k in (10, 11):
        r = rows[k]
        assert r.lost and math.isnan(r.ball_mm) and math.isnan(r.structure_mm)
        assert r.ball_valid == 0 and r.structure_valid == 0
    assert rows[20].lost and math.isnan(rows[20].ball_mm) and rows[20].ball_valid == 0
    good = [k for k in range(n) if k not in (10, 11, 20)]
    assert not any(rows[k].lost for k in good)
    err = np.array([rows[k].ball_mm / MM_PER_PX - ball[k] for k in good])
    assert np.abs(err).max() <= 0.02  # the state survives the gaps


def test_roi_leaving_the_image_is_flagged_and_recovers(scene: RigScene) -> None:
    # the ball ROI spans rows 50..110 of 160; moving up 60 px pushes it out of the top edge
    ball = np.concatenate([np.linspace(0, 60, 13), np.linspace(60, 0, 13)[1:]])
    rng = np.random.default_rng(9)
    frames = [scene.frame(b, 0.0, noise_sigma=2.0, rng=rng) for b in ball]
    tr = _tracker(scene, frames[0])
    rows, reasons = [], []
    for k, img in enumerate(frames):
        rows.append(tr.track(Frame(k, k / 1000.0, img, "mem")))
        reasons.append(tr.last_results["ball"].reason)
    out = ball > 50 - 3  # box top row 50 - shift < interpolation margin (2 px) -> outside
    for r, o, b in zip(rows, out, ball):
        if o:
            assert r.lost and math.isnan(r.ball_mm)
            assert not math.isnan(r.structure_mm)  # the other mesh keeps its value
            assert "leaves the image" in reasons[rows.index(r)]
        elif b < 44:
            assert not r.lost and r.ball_mm / MM_PER_PX == pytest.approx(b, abs=0.02)
    assert out.sum() >= 3 and not rows[-1].lost  # lost while out, then recovered


def test_occluded_points_are_rejected_as_outliers(scene: RigScene) -> None:
    rng = np.random.default_rng(11)
    ref = scene.frame(0.0, 0.0, noise_sigma=2.0, rng=rng)
    img = scene.frame(2.3, 0.0, noise_sigma=2.0, rng=rng)
    # a foreign texture covers the top-left corner of the ball ROI (dust, a glint): the subsets
    # there no longer match; the rule (ZNCC threshold, median +- 3 MAD) must drop them
    img[48:68, 328:350] = rng.integers(0, 256, size=(20, 22), dtype=np.uint8)
    tr = _tracker(scene, ref)
    row = tr.track_image(1, 0.001, img)
    res = tr.last_results["ball"]
    assert not row.lost
    assert 8 <= row.ball_valid < 16
    assert row.ball_mm / MM_PER_PX == pytest.approx(2.3, abs=0.01)
    # the rejected points are those whose subset overlaps the patch
    corners = tr.ball.corners
    hit = (corners[:, 0] < 350) & (corners[:, 0] + 31 > 328) & (corners[:, 1] - 2.3 < 68) \
        & (corners[:, 1] - 2.3 + 31 > 48)
    assert np.all(res.point_valid[~hit])  # untouched points are all kept
    # every kept point agrees with the truth within the rule's floor (0.1 px); true up = -row shift
    assert np.all(np.abs(-res.point_u_px[res.point_valid, 1] - 2.3) <= 0.1)


def test_bad_parameters_and_images_are_refused(scene: RigScene) -> None:
    rig = parse_rig(scene_rig_mapping(scene), "test")
    ref = scene.frame(0.0, 0.0)
    with pytest.raises(RecordingError, match="method"):
        DicTracker(ref, rig.dic, 0.05, method="fft")
    with pytest.raises(RecordingError, match="mm_per_px"):
        DicTracker(ref, rig.dic, -1.0)
    with pytest.raises(RecordingError, match="zncc_min"):
        DicTracker(ref, rig.dic, 0.05, zncc_min=1.5)
    with pytest.raises(RecordingError, match="ball_roi"):
        DicTracker(ref[:, :300], rig.dic, 0.05)
    with pytest.raises(FrameError, match="2-D"):
        DicTracker(np.zeros((4, 4, 3), np.uint8), rig.dic, 0.05)
    edge = DicConfig(31, 10, Roi(0, 10, 61, 61), rig.dic.structure_roi)  # valid ROI, but on the border
    with pytest.raises(RecordingError, match="border"):
        DicTracker(ref, edge, 0.05)
    flat = ref.copy()
    flat[40:120, 320:400] = 90  # the ball ROI shows no pattern
    with pytest.raises(RecordingError, match="dic.ball_roi.*texture"):
        DicTracker(flat, rig.dic, 0.05)
    tr = DicTracker(ref, rig.dic, 0.05)
    with pytest.raises(FrameError, match="frame 3"):
        tr.track(Frame(3, 0.003, ref[:100], "mem"))


def _flights(n: int, fps: float = 1000.0) -> np.ndarray:
    """Ball height (px, up) of a ball bouncing on a plate: free-flight parabolas under 9.81 m/s^2 from a launch
    at 0.1 m/s, 0 at frame 0, with an impact (the height back near 0, the velocity reversed) every 20 frames."""
    g_px = 9.81e3 / MM_PER_PX / fps**2  # px per frame^2
    v0 = 0.1e3 / MM_PER_PX / fps  # px per frame
    k = np.arange(n) % 20
    return v0 * k - 0.5 * g_px * k**2


def test_refining_from_the_prediction_lands_where_the_search_does(scene: RigScene, monkeypatch) -> None:
    # In free flight the quadratic prediction is exact to the noise, so the tracker refines the box straight
    # from it (no ZNCC search); at each impact the prediction is wrong by several px and the frame must go
    # through the search. Both paths end on the same ZNSSD optimum: they may differ only by what the
    # convergence tolerances leave, O(tol_px^2) = 4e-4 px, far below the 0.01 px accuracy goal.
    import vibro_dic.tracker as tracker_module

    n = 96
    ball = _flights(n)
    structure = 15.0 * np.sin(2 * np.pi * 22.0 * np.arange(n) / 1000.0)
    rng = np.random.default_rng(12)
    frames = [scene.frame(b, s, noise_sigma=2.0, rng=rng) for b, s in zip(ball, structure)]

    def run() -> tuple[DicTracker, list]:
        tr = _tracker(scene, frames[0])
        return tr, [tr.track(Frame(k, k / 1000.0, img, "mem")) for k, img in enumerate(frames)]

    fast, rows = run()
    monkeypatch.setattr(tracker_module, "PREDICTION_MAX_ITER", 0)  # every frame searched
    searched, ref_rows = run()
    assert searched.ball.n_predicted == 0 and searched.structure.n_predicted == 0
    impacts = int(np.count_nonzero(np.arange(1, n) % 20 == 0))
    # every frame with a quadratic history (3 frames back within the flight) but those right after an impact
    assert fast.structure.n_predicted == n - 3
    assert n - 3 - 3 * impacts <= fast.ball.n_predicted < n - 3
    for a, b in zip(rows, ref_rows):
        assert not a.lost and not b.lost
        assert (a.ball_valid, a.structure_valid) == (b.ball_valid, b.structure_valid)
        assert abs(a.ball_mm - b.ball_mm) / MM_PER_PX <= 1e-3
        assert abs(a.structure_mm - b.structure_mm) / MM_PER_PX <= 1e-3
    got = np.array([r.ball_mm for r in rows]) / MM_PER_PX
    assert np.sqrt(np.mean((got - ball) ** 2)) <= 0.01  # and both are right


def test_the_driven_structure_is_predicted_as_a_sine_across_dropped_frames(scene: RigScene) -> None:
    # A live tracker that falls behind sees every 7th frame: 7 ms apart, 0.97 rad of a 22 Hz drive. A parabola
    # through three such frames misses the next by pixels (a search, widened), the sine at the drive frequency
    # through them is exact for the driven motion: the box is refined straight from it.
    n, stride, drive_hz, fps = 210, 7, 22.0, 1000.0
    structure = 15.0 * np.sin(2 * np.pi * drive_hz * np.arange(n) / fps + 0.4)
    structure -= structure[0]
    rng = np.random.default_rng(13)
    ks = list(range(0, n, stride))
    frames = {k: scene.frame(0.0, structure[k], noise_sigma=2.0, rng=rng) for k in ks}

    def run(**kw) -> tuple[DicTracker, np.ndarray]:
        tr = _tracker(scene, frames[0], reseed_every=10_000, **kw)
        rows = [tr.track(Frame(k, k / fps, frames[k], "mem")) for k in ks]
        assert not any(r.lost for r in rows)
        return tr, np.array([r.structure_mm for r in rows]) / MM_PER_PX

    sine, got = run(structure_drive_cycles_per_frame=drive_hz / fps)
    parabola, got_parabola = run()
    with_history = len(ks) - 3
    # only the two frames before three are in the history may need a wider search
    assert sine.structure.n_predicted == with_history and sine.structure.n_widened <= 2
    assert parabola.structure.n_widened >= with_history // 2  # the case the sine is for
    assert np.sqrt(np.mean((got - structure[ks]) ** 2)) <= 0.01
    assert np.max(np.abs(got - got_parabola)) <= 1e-3  # the same optimum either way


@pytest.mark.parametrize("cycles", [0.0, 0.5, -0.1, float("nan"), "22"])
def test_a_drive_frequency_beyond_nyquist_or_not_a_number_is_refused(scene: RigScene, cycles) -> None:
    ref = scene.frame(0.0, 0.0)
    with pytest.raises(RecordingError, match="structure_drive_cycles_per_frame"):
        _tracker(scene, ref, structure_drive_cycles_per_frame=cycles)


def test_history_a_whole_drive_period_apart_falls_back_to_the_parabola(scene: RigScene) -> None:
    # 25 Hz at 1000 frames/s: frames 40 apart are one period apart, so three history frames 0, 40, 80 (a long
    # loss between them) cannot determine a sine: the prediction must come from the parabola, not fail
    ref = scene.frame(0.0, 0.0)
    tr = _tracker(scene, ref, structure_drive_cycles_per_frame=25.0 / 1000.0)
    mesh = tr.structure
    for k, u in ((0, 0.0), (40, 1.0), (80, 4.0)):
        mesh.history.append((k, np.array([0.0, u])))
    pred = mesh.predict(81)
    assert np.all(np.isfinite(pred))
    # the parabola through (0, 0), (40, 1), (80, 4) px: u = k^2 / 1600, so 81^2 / 1600 at frame 81
    assert pred[1] == pytest.approx(81.0**2 / 1600.0, abs=1e-9)
