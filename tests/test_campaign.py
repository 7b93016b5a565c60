"""``vibro campaign`` on a Dask cluster, and DIC in chunks on Dask workers (identical dic.csv and dic_quality).

Recordings made once: two synthetic (``vibro synth``, run in parallel), one with an effect (asymmetric
restitution), one control (constant COR 0.7), and one broken (rig.yaml refused). One Dask cluster for the module
(two worker processes), started in a subprocess with rclpy made unimportable (a poisoned ``rclpy`` first on
PYTHONPATH, inherited by the worker processes, that leaves a marker file when anything imports it): the
campaign runs once on it from a subprocess poisoned the same way, and every chunked tracking of this module
runs on its workers too.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO

from vibro_app.campaign.summary import Z_FLAG, flag_disagreeing
from vibro_app.cli import main
from vibro_dic.quality import TrackQuality, dic_quality_section
from vibro_dic.texture import TextureError
from vibro_io.dictrack import read_dic_csv, write_dic_csv
from vibro_io.recording import open_recording
from vibro_model.errors import FrameError

VIBRO = str(REPO / "vibro")
FRAMES = 200  # two tracking segments (re-seed at frame 100): two chunks
POISON = '''import os, pathlib
pathlib.Path(os.environ["VIBRO_TEST_RCLPY_MARKER"]).write_text("rclpy imported by pid %d" % os.getpid())
raise ImportError("rclpy is poisoned in this test: the campaign path must not import it")
'''
#: the module's cluster: vibro's own local cluster (vibro_dic.cluster.dask_client, 2 worker processes), kept
#: up until stdin closes
CLUSTER = """import sys
from vibro_dic.cluster import dask_client
with dask_client(2) as client:
    print(client.scheduler.address, flush=True)
    sys.stdin.read()
"""


def _synth(out: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([VIBRO, "synth", "--out", str(out), "--no-progress", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("campaign") / "sweep"
    root.mkdir()
    procs = [_synth(root / "effect", "--frames", str(FRAMES), "--seed", "11", "--effect", "asymmetric_restitution",
                    "--param", "cor_top=0.6", "--param", "cor_bottom=0.78", "--param", "cor_sigma=0.01"),
             _synth(root / "control", "--frames", str(FRAMES), "--seed", "12", "--effect", "none")]
    for p in procs:
        out, _ = p.communicate(timeout=300)
        assert p.returncode == 0, out
    # broken: the control's first 40 frames without accelerometers, under a rig.yaml with a negative frequency
    broken = root / "broken"
    (broken / "frames").mkdir(parents=True)
    for k in range(40):
        shutil.copy2(root / "control" / "frames" / f"{k:06d}.png", broken / "frames")
    rig = yaml.safe_load((root / "control" / "rig.yaml").read_text())
    assert rig["excitation"]["frequency_hz"] == 22.0
    rig["excitation"]["frequency_hz"] = -22.0
    del rig["accelerometers"]
    (broken / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    return root


@pytest.fixture(scope="module")
def poisoned(tmp_path_factory) -> tuple[dict, Path]:
    """(environment with rclpy poisoned, marker file written by any import of rclpy under it)."""
    tmp = tmp_path_factory.mktemp("poison")
    poison = tmp / "poison" / "rclpy"
    poison.mkdir(parents=True)
    (poison / "__init__.py").write_text(POISON)
    marker = tmp / "rclpy-imported"
    env = dict(os.environ, VIBRO_TEST_RCLPY_MARKER=str(marker))
    env["PYTHONPATH"] = str(poison.parent) + os.pathsep + env.get("PYTHONPATH", "")
    return env, marker


@pytest.fixture(scope="module")
def scheduler(poisoned, tmp_path_factory) -> str:
    """Address of the module's Dask cluster (2 worker processes, rclpy poisoned in them)."""
    env, _ = poisoned
    log = (tmp_path_factory.mktemp("cluster") / "cluster.log").open("w")
    proc = subprocess.Popen([sys.executable, "-c", CLUSTER], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=log, text=True)
    try:
        address = proc.stdout.readline().strip()
        assert address.startswith("tcp://"), Path(log.name).read_text()
        yield address
    finally:
        proc.stdin.close()
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


@pytest.fixture(scope="module")
def client(scheduler):
    from distributed import Client

    with Client(scheduler, timeout=30) as c:
        yield c


@pytest.fixture(scope="module")
def campaign(recordings: Path, poisoned, scheduler: str, tmp_path_factory) -> dict:
    env, marker = poisoned
    out = tmp_path_factory.mktemp("campaign_out") / "out"
    proc = subprocess.run([VIBRO, "campaign", str(recordings), "--out", str(out), "--scheduler", scheduler,
                           "--no-progress"], env=env, capture_output=True, text=True, timeout=600)
    return {"proc": proc, "out": out, "marker": marker, "env": env,
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
        assert row["excitation"] == {"frequency_hz": 22.0, "acceleration_mps2": 27.0}  # synth's defaults, rig.yaml
        results = json.loads((out / name / "results.json").read_text())
        assert row["n_impacts"] == len(results["impacts"])
        # every true impact with a whole flight (~22 ms: 2 impacts per 45 ms cycle) on both sides inside the
        # 0.2 s recording is measured: those more than 10 ms from either end (0.18 s / 22.5 ms: 7 or 8)
        t_meas = np.array([i["t"] for i in results["impacts"]])
        t_end = FRAMES / 1000.0  # synth's 1000 fps
        interior = [i["t"] for i in json.loads(Path(str(recordings / name) + ".truth.json").read_text())["impacts"]
                    if 0.010 < i["t"] < t_end - 0.010]
        assert len(interior) >= 7 and all(np.abs(t_meas - t).min() < 2e-3 for t in interior), (interior, t_meas)
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


def test_resume_skips_unchanged_runs(campaign, recordings: Path, scheduler: str, capsys) -> None:
    out = campaign["out"]
    mtimes = {n: (out / n / "results.json").stat().st_mtime_ns for n in ("effect", "control")}
    frame = recordings / "control" / "frames" / "000007.png"
    st = frame.stat()
    os.utime(frame, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # an input touched: control is redone
    rig = recordings / "broken" / "rig.yaml"  # rig.yaml edited (its content is in the fingerprint): redone
    rig.write_text(rig.read_text().replace("frequency_hz: -22.0", "frequency_hz: 0.0"))
    assert main(["campaign", str(recordings), "--out", str(out), "--scheduler", scheduler, "--no-progress"]) == 1
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
    return {"status": "ok", "excitation": {"frequency_hz": freq, "acceleration_mps2": accel},
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

def _csv_bytes(rows, path: Path) -> bytes:
    write_dic_csv(path, rows)
    return path.read_bytes()


def _json(section: dict) -> str:
    """A results section as text: equal text is equal content (NaN included)."""
    return json.dumps(section, sort_keys=True)


def test_chunked_analyze_and_track_identical_dic_csv_and_dic_quality(campaign, recordings: Path, scheduler: str,
                                                                     tmp_path: Path) -> None:
    from vibro_dic.chunked import segment_starts

    assert segment_starts(0, FRAMES) == [0, 100]
    assert segment_starts(0, 250) == [0, 100, 200] and segment_starts(37, 200) == [0, 63, 163]  # indices 100, 200
    serial_dir = campaign["out"] / "effect"  # analysed by the campaign: DIC in one process (a worker)
    serial_csv = (serial_dir / "dic.csv").read_bytes()
    serial = json.loads((serial_dir / "results.json").read_text())
    out = tmp_path / "chunked"
    assert main(["analyze", str(recordings / "effect"), "--out", str(out), "--scheduler", scheduler,
                 "--no-report", "--no-progress"]) == 0
    assert (out / "dic.csv").read_bytes() == serial_csv
    chunked = json.loads((out / "results.json").read_text())
    assert _json(chunked["dic_quality"]) == _json(serial["dic_quality"])
    correlation = chunked["dic_quality"]["correlation"]["bodies"]
    assert correlation["ball"]["frames"] == correlation["structure"]["frames"] == FRAMES  # each frame once
    assert _json(chunked["impacts"]) == _json(serial["impacts"])
    # the re-seeded frame (first of the second segment) is as accurate as the others: DIC goal 0.01 px, max 0.02 px
    truth = json.loads(Path(str(recordings / "effect") + ".truth.json").read_text())
    ball = np.array(truth["frames"]["ball_mm"])
    track = read_dic_csv(out / "dic.csv")
    err = np.abs(track.ball_mm - (ball - ball[0]))
    assert err[100] <= 0.02 * open_recording(recordings / "effect").rig.camera.mm_per_px, err[100]
    # `vibro track --scheduler ADDRESS` writes the same bytes
    assert main(["track", str(recordings / "effect"), "--out", str(tmp_path / "cli"), "--scheduler", scheduler,
                 "--no-progress"]) == 0
    assert (tmp_path / "cli" / "dic.csv").read_bytes() == serial_csv


def _worse_sigma_px(body: dict) -> np.ndarray:
    """Per subset of a results.json texture body: the predicted sigma (px) of its worse axis (inf: no signal)."""
    return np.array([max(math.inf if s[k] is None else s[k] for k in ("sigma_x_px", "sigma_y_px"))
                     for s in body["subsets"]])


def test_chunked_tracking_lost_frames_texture_and_errors_identical(campaign, recordings: Path, client,
                                                                   tmp_path: Path, caplog) -> None:
    from vibro_dic.chunked import track_rows

    rec_dir = tmp_path / "gappy"
    shutil.copytree(recordings / "control", rec_dir)
    (rec_dir / "frames" / "000100.png").unlink()  # dropped, at a segment start
    (rec_dir / "frames" / "000150.png").write_bytes(b"not a png")  # unreadable, mid-segment
    # a texture threshold stricter than the default: well-textured subsets (tracked by default) become unusable;
    # every body keeps >= 70 % of its subsets (the tracker needs 50 %)
    default = json.loads((campaign["out"] / "control" / "results.json").read_text())["dic_quality"]
    sigma = {b: _worse_sigma_px(default["texture"]["bodies"][b]) for b in ("ball", "structure")}
    strict = max(float(np.quantile(s, 0.7)) for s in sigma.values())
    unusable = {b: np.flatnonzero(s > strict) for b, s in sigma.items()}
    rec = open_recording(rec_dir)
    caplog.set_level("WARNING", logger="vibro_dic.tracker")
    runs = {}
    for name, kwargs in (("serial", {}), ("chunked", {"client": client})):
        caplog.clear()
        quality = TrackQuality()
        data = _csv_bytes(track_rows(rec, quality=quality, max_subset_sigma_px=strict, **kwargs),
                          tmp_path / f"{name}.csv")
        log = [r.getMessage() for r in caplog.records if r.name == "vibro_dic.tracker"]
        runs[name] = (data, _json(dic_quality_section(quality.texture, quality)), log, quality.summary())
    assert runs["chunked"][0] == runs["serial"][0]
    assert runs["chunked"][1] == runs["serial"][1]
    assert runs["chunked"][2] == runs["serial"][2]
    log = runs["serial"][2]
    skipped = [m for m in log if " skipped: " in m]
    assert len(skipped) == 2 and "frame 100" in skipped[0] and "frame 150" in skipped[1]
    # the texture warnings: once per pass (not per chunk), one line per body with unusable subsets
    texture_lines = [m for m in log if m.startswith("texture: ")]
    assert len(texture_lines) == sum(1 for idx in unusable.values() if idx.size) >= 1
    kept = runs["serial"][3]["bodies"]
    for body, idx in unusable.items():  # left out in every chunk, though tracked when the threshold allows
        assert np.all(np.asarray(kept[body]["subset_kept_fraction"])[idx] == 0.0), body
        assert np.all(np.asarray(default["correlation"]["bodies"][body]["subset_kept_fraction"])[idx] > 0.5), body
    track = read_dic_csv(tmp_path / "serial.csv")
    assert list(np.nonzero(track.lost)[0]) == [100, 150]
    assert track.good[101]  # the frame after a dropped segment start is found again
    # too many unreadable frames (> 5 % of 200: the 11th), in both chunks: the same refusal after the same rows
    for k in [*range(95, 100), *range(101, 107)]:
        (rec_dir / "frames" / f"{k:06d}.png").write_bytes(b"broken")
    rec = open_recording(rec_dir)
    errors = []
    for kwargs in ({}, {"client": client}):
        rows = []
        with pytest.raises(FrameError) as info:
            for row in track_rows(rec, **kwargs):
                rows.append(row)
        errors.append((str(info.value), len(rows)))
    assert errors[0] == errors[1] and "unreadable" in errors[0][0] and errors[0][1] == 106  # refused at frame 106


def test_chunked_refusals_identical(recordings: Path, client, tmp_path: Path) -> None:
    from vibro_dic.chunked import track_rows

    # the texture check refuses before any chunk is tracked, with the message of one process (and a local
    # cluster is not even started)
    rec = open_recording(recordings / "control")
    messages = []
    for kwargs in ({}, {"client": client}, {"workers": 2}):
        with pytest.raises(TextureError) as info:
            list(track_rows(rec, max_subset_sigma_px=1e-4, **kwargs))
        messages.append(str(info.value))
    assert messages[0] == messages[1] == messages[2]
    assert "texture check refused" in messages[0] and "dic.ball_roi" in messages[0] and "structure_roi" in messages[0]
    # an unreadable reference: the same error
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


def test_cluster_workers_never_imported_rclpy(poisoned, campaign) -> None:
    """Last: the campaign's tasks and every chunk of this module ran on the poisoned workers."""
    _, marker = poisoned
    assert not marker.exists(), marker.read_text()
