"""The ball's in-plane spin: DIC rotation vs the synthetic rig's truth, the noise floor, and the COR-spin test.

Three 300-frame recordings of the synthetic rig (built once for the module): a ball whose spin is drawn
anew at each impact (N(0, 0.3 rad/s)) with a COR scatter independent of it; the same spin with the COR
depending on the spin change (COR += 0.1 s/rad x change, std 0.1 x 0.3 sqrt(2) = 0.042, beside a 0.01
independent scatter: a correlation of 0.042 / sqrt(0.042^2 + 0.01^2) = 0.97 expected, where n = 13
impacts need |rho| > ~0.75 for p < 0.01 / 3); and a ball that does not spin. Tolerances come from the
tracker's own noise figure: the angle's 1-sigma is the subsets' residual displacement noise over the
root-sum-square of their lever arms (vibro_dic.rotation), and a flight's spin 1-sigma is that over
sqrt(sum (t - mean t)^2).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vibro_dic.tracker import track_recording
from vibro_fit.identify import identify
from vibro_fit.results import results_model
from vibro_fit.spin import CORRELATION_ALPHA, TESTS, ball_spin_section
from vibro_io.dictrack import DIC_COLUMNS, LEGACY_DIC_COLUMNS, DicTrack, read_dic_csv, write_dic_csv
from vibro_io.recording import open_recording
from vibro_sim.synth import SynthConfig, synthesize

FRAMES = 300


def _case(tmp_path_factory, name: str, **cfg) -> dict:
    out = tmp_path_factory.mktemp("spin") / name
    truth = synthesize(out, SynthConfig(frames=FRAMES, seed=3, accel=False, **cfg), progress=False)
    rec = open_recording(out)
    track = DicTrack.from_frames(track_recording(rec))
    ident = identify(track, rec.rig)
    doc = results_model(ident, str(out))
    return {"truth": truth, "track": track, "doc": doc, "section": ball_spin_section(track, doc.flights, doc.impacts)}


@pytest.fixture(scope="module")
def independent(tmp_path_factory):
    return _case(tmp_path_factory, "independent", spin_sigma_rad_s=0.3, cor_scatter=0.015)


@pytest.fixture(scope="module")
def coupled(tmp_path_factory):
    return _case(tmp_path_factory, "coupled", spin_sigma_rad_s=0.3, cor_scatter=0.01,
                 spin_cor_coupling_s_per_rad=0.1)


@pytest.fixture(scope="module")
def still_ball(tmp_path_factory):
    return _case(tmp_path_factory, "still", cor_scatter=0.015)


def _truth_omega(truth: dict, t_mid: float) -> float:
    rows = [f["omega_rad_s"] for f in truth["spin"]["flights"] if f["t_start"] <= t_mid <= f["t_end"]]
    assert len(rows) == 1
    return rows[0]


def test_frame_angle_matches_truth_within_the_subset_noise(independent):
    track, truth = independent["track"], independent["truth"]
    true = np.array(truth["spin"]["frames_rot_rad"])
    assert np.ptp(true) > 0.02  # the ball really turns (many times the noise) and stays trackable
    assert np.max(np.abs(true)) < 0.05
    err = track.ball_rot_rad - true
    assert np.all(np.isfinite(err))
    # frame 0 is the reference; from frame 1 on the reference's own noise is a constant offset (~1 sigma)
    sigma = float(np.median(track.ball_rot_std_rad[1:]))
    assert 0 < sigma < 1e-3
    assert abs(np.mean(err[1:])) < 3 * sigma
    assert np.std(err[1:]) < 2 * sigma


def test_flight_spin_matches_truth(independent):
    sec, truth = independent["section"], independent["truth"]
    assert sec["available"] and sec["spin_detected"]
    flights = sec["flights"]
    assert len(flights) >= 10
    z = np.array([(f["omega_rad_s"] - _truth_omega(truth, 0.5 * (f["t_start"] + f["t_end"]))) / f["omega_std_rad_s"]
                  for f in flights])
    assert np.max(np.abs(z)) < 4.0  # each flight within 4 sigma
    assert math.sqrt(np.mean(z ** 2)) < 2.0  # and the sigma is not understated
    # the spin change at each impact is the truth's within its sigma
    t_imp = {round(i["t"], 3): i["spin_change_rad_s"] for i in truth["spin"]["impacts"]}
    rows = sec["impacts"]
    assert len(rows) >= 8
    for r in rows:
        true = min(t_imp.items(), key=lambda kv: abs(kv[0] - r["t"]))[1]
        assert abs(r["spin_change_rad_s"] - true) < 4 * r["spin_change_std_rad_s"] + 0.03 * abs(true)


def test_independent_cor_scatter_shows_no_correlation(independent):
    c = independent["section"]["correlation"]
    assert c["n"] >= 10
    # three Spearman tests at 0.01/3 each: under independence a false alarm has probability <= 1 %
    assert set(c["tests"]) == set(TESTS)
    assert c["significant"] is False
    assert min(t["p"] for t in c["tests"].values()) >= CORRELATION_ALPHA / len(TESTS)
    assert independent["section"]["statement"].startswith("COR scatter does not correlate with spin")


def test_cor_depending_on_spin_change_is_found(coupled):
    sec = coupled["section"]
    assert sec["spin_detected"]
    c = sec["correlation"]
    assert c["significant"] is True
    assert c["strongest"] == "spin_change"
    assert c["tests"]["spin_change"]["rho"] > 0.6  # the coupling is positive
    assert c["tests"]["spin_change"]["p"] < CORRELATION_ALPHA / len(TESTS)
    assert sec["statement"].startswith("COR scatter correlates with the spin change")


def test_non_spinning_ball_reports_no_spin(still_ball):
    sec, track = still_ball["section"], still_ball["track"]
    assert "spin" not in still_ball["truth"]
    assert sec["available"] and sec["spin_detected"] is False
    assert sec["chi2_p"] >= 0.01
    for f in sec["flights"]:
        assert abs(f["omega_rad_s"]) < 4 * f["omega_std_rad_s"]
    noise = sec["noise"]
    # the angle scatter about each flight's line agrees with what the subsets' residuals predict
    assert 0.5 < noise["angle_measured_rad"] / noise["angle_expected_rad"] < 2.0
    assert sec["statement"].startswith("no spin above the DIC noise")
    # and the still ball's angle stays at the noise: no rotation from translation
    assert np.std(track.ball_rot_rad[1:]) < 2 * np.median(track.ball_rot_std_rad[1:])


def test_dic_csv_carries_rotation_and_reads_old_files(independent, tmp_path):
    track = independent["track"]
    rows = [r for r in _rows(track)]
    write_dic_csv(tmp_path / "dic.csv", rows)
    assert (tmp_path / "dic.csv").read_text().splitlines()[0] == ",".join(DIC_COLUMNS)
    back = read_dic_csv(tmp_path / "dic.csv")
    assert np.allclose(back.ball_rot_rad, track.ball_rot_rad, rtol=1e-6, atol=1e-12)
    # a dic.csv written before the rotation columns: read, rotation unknown, no spin claimed
    old = tmp_path / "old.csv"
    lines = (tmp_path / "dic.csv").read_text().splitlines()
    old.write_text("\n".join(",".join(line.split(",")[:len(LEGACY_DIC_COLUMNS)]) for line in lines) + "\n")
    legacy = read_dic_csv(old)
    assert np.allclose(legacy.ball_mm, back.ball_mm) and np.all(np.isnan(legacy.ball_rot_rad))
    sec = ball_spin_section(legacy, [], [])
    assert sec["available"] is False and sec["spin_detected"] is False and "no spin reported" in sec["statement"]


def _rows(track: DicTrack):
    from vibro_io.dictrack import FrameTrack

    for k in range(len(track)):
        yield FrameTrack(frame=int(track.frame[k]), t_s=float(track.t_s[k]), ball_mm=float(track.ball_mm[k]),
                         structure_mm=float(track.structure_mm[k]), ball_valid=int(track.ball_valid[k]),
                         structure_valid=int(track.structure_valid[k]),
                         ball_zncc=float(track.ball_zncc[k]), structure_zncc=float(track.structure_zncc[k]),
                         lost=bool(track.lost[k]),
                         ball_rot_rad=float(track.ball_rot_rad[k]), ball_rot_std_rad=float(track.ball_rot_std_rad[k]))


def test_spinning_renderer_at_rest_draws_the_still_ball():
    """The analytic (spinning) ball patch at angle 0 is the Fourier-shifted still patch: same impulses, same
    blur, same edge, to well under a gray level inside the disc; and turning it moves the texture."""
    from vibro_sim.synth.render import Renderer, choose_layout

    layout = choose_layout(160, 480, 4.77, 16.6, 1.41, None, 31)
    still = Renderer(layout, np.random.default_rng([3, 1]))
    spin = Renderer(layout, np.random.default_rng([3, 1]), spin=True)
    pv, pa = spin.spinning_ball.patch(0.37, 0.0)
    fv, fa = still.ball_layer.shifted(0.37)
    inside = fa > 0.999
    assert np.max(np.abs(pv - fv)[inside]) < 0.1 and np.max(np.abs(pa - fa)) < 1e-4
    turned, _ = spin.spinning_ball.patch(0.37, 0.03)
    assert np.std((turned - pv)[inside]) > 1.0


@pytest.mark.parametrize("key, value", [("spin_sigma_rad_s", -0.1), ("spin_rad_s", float("nan")),
                                        ("spin_cor_coupling_s_per_rad", 5.0)])
def test_bad_spin_options_are_refused(key, value):
    from vibro_sim.synth import SynthError

    with pytest.raises(SynthError, match=key):
        SynthConfig(**{key: value})


def _through_cdr(track: DicTrack) -> list:
    """The track as dic_tracker publishes it (rclpy DicFrames, CDR bytes) and as a bag reader decodes it (rosbags,
    vibro's typestore)."""
    from rclpy.serialization import serialize_message

    from vibro_dic.dic_tracker_node import dic_message
    from vibro_ros.bags import make_typestore

    store = make_typestore()
    return [store.deserialize_cdr(serialize_message(dic_message(row, (4, 4))), "vibro_msgs/msg/DicFrame")
            for row in _rows(track)]


def test_graph_path_spin_per_flight_matches_truth(independent):
    """The graph's DicFrames carry the rotation; vibro results' section of them is analyze's, within sigma of truth."""
    from vibro_app.bag_results import ball_spin_from_frames

    frames = _through_cdr(independent["track"])
    assert np.allclose([m.ball_rot_rad for m in frames], independent["track"].ball_rot_rad, rtol=0, atol=0,
                       equal_nan=True)  # float64 in CDR: bit for bit
    doc = independent["doc"]
    sec, why_not = ball_spin_from_frames(frames, doc.flights, doc.impacts)
    assert why_not == "" and sec["available"] and sec["spin_detected"]
    assert sec == independent["section"]  # the same core on the same numbers: analyze's section, field for field
    z = np.array([(f["omega_rad_s"] - _truth_omega(independent["truth"], 0.5 * (f["t_start"] + f["t_end"])))
                  / f["omega_std_rad_s"] for f in sec["flights"]])
    assert len(z) >= 10 and np.max(np.abs(z)) < 4.0


def test_dicframes_without_a_measured_rotation_give_no_spin(independent):
    """A DicFrame decoded from a bag recorded before the rotation fields, or one whose publisher left them at the
    ROS default 0, carries no rotation: NaN, never a zero angle with a zero sigma."""
    from old_msgdefs import old_dicframe_typestore

    from vibro_app.bag_results import ball_spin_from_frames
    from vibro_msgs.msg import DicFrame
    from vibro_ros.convert import dic_track_from_messages

    old = old_dicframe_typestore()
    old_type = old.types["vibro_msgs/msg/DicFrame"]
    header = old.types["std_msgs/msg/Header"](old.types["builtin_interfaces/msg/Time"](0, 0), "camera")
    old_frame = old.deserialize_cdr(old.serialize_cdr(old_type(header, 0, 0.0, 0.0, 0.0, 4, 4, 4, 4, 1.0, 1.0, False,
                                                               "", 0, ""), old_type.__msgtype__), old_type.__msgtype__)
    defaults = [DicFrame(frame_index=k, t_s=k / 1000.0, ball_mm=0.1 * k, structure_mm=0.0) for k in range(50)]
    assert defaults[1].ball_rot_rad == 0.0 and defaults[1].ball_rot_std_rad == 0.0  # the ROS default
    for track in (dic_track_from_messages([old_frame]), dic_track_from_messages(defaults)):
        assert np.all(np.isnan(track.ball_rot_rad)) and np.all(np.isnan(track.ball_rot_std_rad))
    doc = independent["doc"]
    sec, _ = ball_spin_from_frames(defaults, doc.flights, doc.impacts)
    assert sec["available"] is False and sec["spin_detected"] is False and sec["flights"] == []
    assert ball_spin_from_frames([old_frame], doc.flights, doc.impacts)[0] is None
    assert ball_spin_from_frames([], doc.flights, doc.impacts)[0] is None
