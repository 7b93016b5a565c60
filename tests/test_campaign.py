"""``vibro campaign`` on a Dask LocalCluster, and DIC in chunks on Dask workers (identical dic.csv).

Three synthetic recordings made once (``vibro synth``, run in parallel): one with an effect (asymmetric
restitution), one control (constant COR 0.7), one broken (rig.yaml refused). The campaign runs once in a
subprocess with rclpy made unimportable (a poisoned ``rclpy`` first on PYTHONPATH, inherited by the Dask
worker processes, that leaves a marker file when anything imports it).
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO

from vibro_bringup.campaign.summary import Z_FLAG, flag_disagreeing
from vibro_bringup.cli import main
from vibro_io.dictrack import read_dic_csv, write_dic_csv
from vibro_io.errors import FrameError
from vibro_io.recording import open_recording

VIBRO = str(REPO / "vibro")
FRAMES = 250  # three tracking segments (re-seeds at frames 100 and 200)
POISON = '''import os, pathlib
pathlib.Path(os.environ["VIBRO_TEST_RCLPY_MARKER"]).write_text("rclpy imported by pid %d" % os.getpid())
raise ImportError("rclpy is poisoned in this test: the campaign path must not import it")
'''


def _synth(out: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([VIBRO, "synth", "--out", str(out), "--no-progress", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("campaign") / "sweep"
    root.mkdir()
    procs = [_synth(root / "effect", "--frames", str(FRAMES), "--seed", "11", "--effect", "asymmetric_restitution",
                    "--param", "cor_top=0.6", "--param", "cor_bottom=0.78", "--param", "cor_sigma=0.01"),
             _synth(root / "control", "--frames", str(FRAMES), "--seed", "12", "--effect", "none"),
             _synth(root / "broken", "--frames", "40", "--seed", "13", "--no-accel")]
    for p in procs:
        out, _ = p.communicate(timeout=300)
        assert p.returncode == 0, out
    rig = root / "broken" / "rig.yaml"
    text = rig.read_text()
    assert "frequency_hz: 22.0" in text
    rig.write_text(text.replace("frequency_hz: 22.0", "frequency_hz: -22.0"))
    return root


def _poisoned_env(tmp: Path) -> tuple[dict, Path]:
    poison = tmp / "poison" / "rclpy"
    poison.mkdir(parents=True)
    (poison / "__init__.py").write_text(POISON)
    marker = tmp / "rclpy-imported"
    env = dict(os.environ, VIBRO_TEST_RCLPY_MARKER=str(marker))
    env["PYTHONPATH"] = str(poison.parent) + os.pathsep + env.get("PYTHONPATH", "")
    return env, marker


@pytest.fixture(scope="module")
def campaign(recordings: Path, tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("campaign_out")
    env, marker = _poisoned_env(tmp)
    out = tmp / "out"
    t0 = time.perf_counter()
    proc = subprocess.run([VIBRO, "campaign", str(recordings), "--out", str(out), "--workers", "2", "--no-progress"],
                          env=env, capture_output=True, text=True, timeout=600)
    return {"proc": proc, "out": out, "marker": marker, "env": env, "wall_s": time.perf_counter() - t0,
            "doc": json.loads((out / "campaign.json").read_text()) if (out / "campaign.json").is_file() else None}


def _row(doc: dict, name: str) -> dict:
    return next(r for r in doc["runs"] if r["name"] == name)


def test_campaign_runs_without_rclpy(campaign) -> None:
    # the poison is live: importing rclpy under this environment leaves the marker (so the test can fail)
    probe = subprocess.run([sys.executable, "-c", "import rclpy"], env=dict(
        campaign["env"], VIBRO_TEST_RCLPY_MARKER=str(campaign["marker"]) + ".probe"), capture_output=True)
    assert probe.returncode != 0 and Path(str(campaign["marker"]) + ".probe").is_file()
    assert campaign["doc"] is not None, campaign["proc"].stderr
    assert not campaign["marker"].exists(), campaign["marker"].read_text()


def test_bad_recording_reported_not_fatal(campaign) -> None:
    proc, doc = campaign["proc"], campaign["doc"]
    assert proc.returncode == 1, proc.stderr  # ran, one run failed
    assert "Traceback" not in proc.stderr
    s = doc["summary"]
    assert (s["n_runs"], s["n_ok"], s["n_failed"]) == (3, 2, 1)
    [failed] = s["failed"]
    assert failed["name"] == "broken"
    assert "rig.yaml" in failed["reason"] and "excitation.frequency_hz" in failed["reason"]
    assert "\n" not in failed["reason"]
    assert f"failed         broken: {failed['reason']}" in proc.stdout
    assert _row(doc, "broken")["status"] == "failed"


def _truth_cor_by_plate(recording: Path, results: dict) -> dict[str, float]:
    """Mean true COR per plate over the impacts the analysis measured (matched by time within 2 ms)."""
    truth = json.loads(Path(str(recording) + ".truth.json").read_text())
    t_true = np.array([i["t"] for i in truth["impacts"]])
    out = {}
    for plate in ("top", "bottom"):
        cors = []
        for imp in results["impacts"]:
            if imp["plate"] != plate:
                continue
            k = int(np.argmin(np.abs(t_true - imp["t"])))
            assert abs(t_true[k] - imp["t"]) < 2e-3 and truth["impacts"][k]["plate"] == plate
            cors.append(truth["impacts"][k]["cor"])
        out[plate] = float(np.mean(cors))
    return out


def test_campaign_rows_against_truth(campaign, recordings: Path) -> None:
    doc, out = campaign["doc"], campaign["out"]
    for name in ("effect", "control"):
        row = _row(doc, name)
        assert row["status"] == "ok" and not row["resumed"]
        assert row["excitation"] == {"frequency_hz": 22.0, "acceleration_ms2": 27.0}  # synth's defaults, rig.yaml
        results = json.loads((out / name / "results.json").read_text())
        assert row["n_impacts"] == len(results["impacts"]) >= 8  # 2 impacts per 45 ms cycle over 0.25 s
        truth = _truth_cor_by_plate(recordings / name, results)
        for plate in ("top", "bottom"):
            # per-impact COR from DIC is good to ~1e-3 here (noise floor 5e-5, identification a few 1e-4)
            assert row["cor"][plate]["n"] >= 4
            assert abs(row["cor"][plate]["mean"] - truth[plate]) < 3e-3, (name, plate, row["cor"], truth)
    control, effect = _row(doc, "control"), _row(doc, "effect")
    assert control["findings"] == []
    [finding] = effect["findings"]
    assert finding["effect"] == "asymmetric_restitution" and finding["where"]
    law = {"cor_top": 0.6, "cor_bottom": 0.78}  # the synth's law; per-impact scatter sigma 0.01 around it
    for key, true in law.items():
        p = finding["parameters"][key]
        assert p["std"] > 0 and abs(p["value"] - true) < 3 * p["std"] + 0.01, (key, p)


def test_campaign_table_figures_and_html(campaign) -> None:
    doc, out = campaign["doc"], campaign["out"]
    with (out / "campaign.csv").open(newline="") as handle:
        rows = {r["run"]: r for r in csv.DictReader(handle)}
    assert set(rows) == {"effect", "control", "broken"}
    for name in ("effect", "control"):
        j = _row(doc, name)
        assert math.isclose(float(rows[name]["cor_top_mean"]), j["cor"]["top"]["mean"], rel_tol=1e-5)
        assert int(rows[name]["cor_bottom_n"]) == j["cor"]["bottom"]["n"]
        assert float(rows[name]["excitation_frequency_hz"]) == 22.0
    assert rows["effect"]["findings"].startswith("asymmetric_restitution(cor_top = ")
    assert "±" in rows["effect"]["findings"]
    assert rows["broken"]["status"] == "failed" and rows["broken"]["reason"] == doc["summary"]["failed"][0]["reason"]
    import matplotlib.image

    for name in ("cor_vs_speed.png", "cor_vs_excitation.png"):
        img = matplotlib.image.imread(out / name)
        assert img.shape[0] > 200 and img.shape[1] > 400 and img[..., :3].std() > 0.01  # a drawn figure
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 2
    for name in ("effect", "control", "broken", "asymmetric_restitution", "excitation.frequency_hz"):
        assert name in html
    for name in ("effect", "control"):  # each run's own analyze outputs
        assert (out / name / "report.html").is_file() and (out / name / "dic.csv").is_file()


def test_resume_skips_unchanged_runs(campaign, recordings: Path, capsys) -> None:
    out = campaign["out"]
    mtimes = {n: (out / n / "results.json").stat().st_mtime_ns for n in ("effect", "control")}
    frame = recordings / "control" / "frames" / "000007.png"
    st = frame.stat()
    os.utime(frame, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # an input touched: control is redone
    rig = recordings / "broken" / "rig.yaml"  # rig.yaml edited (its content is in the fingerprint): redone
    rig.write_text(rig.read_text().replace("frequency_hz: -22.0", "frequency_hz: 0.0"))
    assert main(["campaign", str(recordings), "--out", str(out), "--workers", "2", "--no-progress"]) == 1
    doc = json.loads((out / "campaign.json").read_text())
    assert _row(doc, "effect")["resumed"] and not _row(doc, "control")["resumed"]
    assert (out / "effect" / "results.json").stat().st_mtime_ns == mtimes["effect"]
    assert (out / "control" / "results.json").stat().st_mtime_ns > mtimes["control"]
    broken = _row(doc, "broken")
    assert not broken["resumed"] and broken["status"] == "failed" and "got 0.0" in broken["reason"]
    assert doc["summary"]["n_resumed"] == 1
    # nothing changed: nothing redone (the bad recording is not retried either), no cluster started
    assert main(["campaign", str(recordings), "--out", str(out), "--no-progress"]) == 1
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["summary"]["n_resumed"] == 2 and doc["timing"]["cluster_start_s"] is None
    assert _row(doc, "broken")["resumed"] and "got 0.0" in _row(doc, "broken")["reason"]
    assert "failed         broken: " in capsys.readouterr().out


def test_list_file_missing_recording_and_bad_input(campaign, recordings: Path, tmp_path: Path, capsys) -> None:
    listing = recordings / "runs.txt"
    listing.write_text("# two runs\neffect\n\nnot_there   # missing\n")
    try:
        out = tmp_path / "listed"
        shutil.copytree(campaign["out"] / "effect", out / "effect")  # its outputs, with their fingerprint
        assert main(["campaign", str(listing), "--out", str(out), "--workers", "1", "--no-progress"]) == 1
        doc = json.loads((out / "campaign.json").read_text())
        assert [r["name"] for r in doc["runs"]] == ["effect", "not_there"]
        assert _row(doc, "effect")["status"] == "ok"
        assert "not_there" in _row(doc, "not_there")["reason"]
        assert _row(doc, "effect")["resumed"] and doc["timing"]["cluster_start_s"] is None  # nothing to run
        listing.write_text("effect\n./effect\n")
        capsys.readouterr()
        assert main(["campaign", str(listing), "--out", str(out), "--no-progress"]) == 2
        assert "line 2" in capsys.readouterr().err
    finally:
        listing.unlink()
    assert main(["campaign", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")]) == 2
    assert "no such folder or list file" in capsys.readouterr().err
    assert main(["campaign", str(recordings), "--out", str(tmp_path / "o"), "--workers", "0"]) == 2
    assert "--workers" in capsys.readouterr().err


def _row_dict(mean: float, std: float, n: int, freq: float = 22.0, accel: float = 27.0) -> dict:
    cor = {"mean": mean, "std": std, "n": n}
    return {"status": "ok", "excitation": {"frequency_hz": freq, "acceleration_ms2": accel},
            "cor": {"top": cor, "bottom": dict(cor)}, "flags": []}


def test_flag_rule() -> None:
    # five repeats at 0.70 with run-to-run spread 0.005, one at 0.60: only that one disagrees
    rows = [_row_dict(m, 0.02, 6) for m in (0.700, 0.705, 0.695, 0.702, 0.698)] + [_row_dict(0.60, 0.02, 6)]
    flag_disagreeing(rows)
    assert [bool(r["flags"]) for r in rows] == [False] * 5 + [True]
    assert {g["plate"] for g in rows[-1]["flags"]} == {"top", "bottom"} and rows[-1]["flags"][0]["z"] < -Z_FLAG
    # another excitation is another group: two runs there are too few to judge
    rows = [_row_dict(0.70, 0.02, 6), _row_dict(0.70, 0.02, 6), _row_dict(0.70, 0.02, 6),
            _row_dict(0.50, 0.02, 6, accel=40.0), _row_dict(0.90, 0.02, 6, accel=40.0)]
    flag_disagreeing(rows)
    assert not any(r["flags"] for r in rows)
    # runs agreeing better than their noise: a difference within it (0.01 < 3.5 x 0.02/sqrt(4)) is not flagged
    rows = [_row_dict(0.700, 0.02, 4) for _ in range(4)] + [_row_dict(0.710, 0.02, 4)]
    flag_disagreeing(rows)
    assert not any(r["flags"] for r in rows)


# --- DIC in chunks on Dask workers --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def client():
    from vibro_dic.cluster import dask_client

    with dask_client(2) as c:
        yield c


def _csv_bytes(rows, path: Path) -> bytes:
    write_dic_csv(path, rows)
    return path.read_bytes()


def test_chunked_tracking_identical_dic_csv(recordings: Path, client, tmp_path: Path) -> None:
    from vibro_dic.chunked import segment_starts, track_rows

    rec = open_recording(recordings / "effect")
    assert segment_starts(0, FRAMES) == [0, 100, 200]
    serial = _csv_bytes(track_rows(rec), tmp_path / "serial.csv")
    chunked = _csv_bytes(track_rows(rec, client=client), tmp_path / "chunked.csv")
    assert chunked == serial
    # the re-seeded frames (first of each segment) are as accurate as the others: DIC goal 0.01 px, max 0.02 px
    truth = json.loads(Path(str(recordings / "effect") + ".truth.json").read_text())
    ball = np.array(truth["frames"]["ball_mm"])
    track = read_dic_csv(tmp_path / "serial.csv")
    err = np.abs(track.ball_mm - (ball - ball[0]))
    assert err[[100, 200]].max() <= 0.02 * rec.rig.camera.mm_per_px, err[[100, 200]]
    # the CLI on an existing cluster (`vibro track --scheduler ADDRESS`) writes the same bytes
    assert main(["track", str(recordings / "effect"), "--out", str(tmp_path / "cli"), "--scheduler",
                 client.scheduler.address, "--no-progress"]) == 0
    assert (tmp_path / "cli" / "dic.csv").read_bytes() == serial


def test_chunked_tracking_lost_frames_and_errors_identical(recordings: Path, client, tmp_path: Path, caplog) -> None:
    from vibro_dic.chunked import track_rows

    rec_dir = tmp_path / "gappy"
    shutil.copytree(recordings / "control", rec_dir)
    (rec_dir / "frames" / "000100.png").unlink()  # dropped, at a segment start
    (rec_dir / "frames" / "000150.png").write_bytes(b"not a png")  # unreadable, mid-segment
    rec = open_recording(rec_dir)
    caplog.set_level("WARNING", logger="vibro_dic.tracker")
    serial = _csv_bytes(track_rows(rec), tmp_path / "serial.csv")
    serial_log = [r.getMessage() for r in caplog.records if r.name == "vibro_dic.tracker"]
    caplog.clear()
    chunked = _csv_bytes(track_rows(rec, client=client), tmp_path / "chunked.csv")
    chunked_log = [r.getMessage() for r in caplog.records if r.name == "vibro_dic.tracker"]
    assert chunked == serial
    assert chunked_log == serial_log and len(serial_log) == 2 and "frame 150" in serial_log[1]
    track = read_dic_csv(tmp_path / "serial.csv")
    assert list(np.nonzero(track.lost)[0]) == [100, 150]
    assert track.good[101]  # the frame after a dropped segment start is found again
    # too many unreadable frames (> 5 %, across chunks): the same refusal, at the same frame
    for k in range(30, 250, 16):
        (rec_dir / "frames" / f"{k:06d}.png").write_bytes(b"broken")
    rec = open_recording(rec_dir)
    errors = []
    for kwargs in ({}, {"client": client}):
        rows = []
        with pytest.raises(FrameError) as info:
            for row in track_rows(rec, **kwargs):
                rows.append(row)
        errors.append((str(info.value), len(rows)))
    assert errors[0] == errors[1] and "unreadable" in errors[0][0]


def test_chunked_reference_error_identical(recordings: Path, client, tmp_path: Path) -> None:
    from vibro_dic.chunked import track_rows

    rec_dir = tmp_path / "noref"
    shutil.copytree(recordings / "control", rec_dir)
    rec = open_recording(rec_dir)  # frame 0 readable when opened, spoilt afterwards
    (rec_dir / "frames" / "000000.png").write_bytes(b"gone")
    messages = []
    for kwargs in ({}, {"client": client}):
        with pytest.raises(FrameError) as info:
            list(track_rows(rec, **kwargs))
        messages.append(str(info.value))
    assert messages[0] == messages[1] and "(reference)" in messages[0]
