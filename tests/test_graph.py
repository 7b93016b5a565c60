"""The whole node graph in separate processes: vibro graph vs vibro analyze, bag results, lost frames."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from domains import private_domain

VIBRO = [sys.executable, "-m", "vibro_app.cli"]


def _vibro(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_DOMAIN_ID=private_domain(), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=timeout, env=env)


@pytest.fixture(scope="module")
def recording(reference_run: dict) -> Path:
    """The shared run's recording (300 frames); tests copy it before changing anything."""
    return reference_run["rec"]


#: Data-time field of each stamped message type (its header stamp must be origin + this).
DATA_TIME_FIELDS = {"vibro_msgs/msg/DicFrame": "t_s", "vibro_msgs/msg/AccelBlock": "t_start_s",
                    "vibro_msgs/msg/AccelImpact": "t_s", "vibro_msgs/msg/ImpactEstimate": "t_s",
                    "vibro_msgs/msg/FreeFlight": "t_end_s"}


def _stamps_on_the_lab_clock(bag: Path, frame0_window_ns: tuple[int, int], duration_s: float) -> dict[int, int]:
    """Check the header stamps of every data message in ``bag`` against the lab clock; return
    {DicFrame frame_index: stamp ns}. The origin comes from the bag's metadata; frame 0 (rig t0_s) must be
    at a wall time in ``frame0_window_ns``; every stamp within the run's data span after the origin, and
    stamp - origin == the message's own data time to 1 us."""
    from vibro_io.rig import parse_rig
    from vibro_ros.bags import deserialize, make_typestore, read_custom_data, read_messages

    custom = read_custom_data(bag)
    origin = int(custom["vibro.time_origin_unix_ns"])
    cam = parse_rig(yaml.safe_load(custom["vibro.rig_yaml"])).camera
    frame0 = origin + round(cam.t0_s * 1e9)
    assert frame0_window_ns[0] <= frame0 <= frame0_window_ns[1], (frame0, frame0_window_ns)
    store = make_typestore()
    checked: dict[str, int] = {}
    dic_stamps = {}
    for m in read_messages(bag):
        msg = deserialize(m, store)
        if not hasattr(msg, "header"):
            continue
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if m.msg_type == "diagnostic_msgs/msg/DiagnosticArray" or m.msg_type.endswith("StreamStatus"):
            continue  # stamped with the node's clock when sent, not with data time
        # every data stamp is on the wall clock of the run, within the recording's span after the origin
        assert origin - 1_000_000_000 <= stamp <= origin + round((cam.t0_s + duration_s + 1) * 1e9), (m.topic, stamp)
        field = DATA_TIME_FIELDS.get(m.msg_type)
        if field is not None:
            assert abs((stamp - origin) - getattr(msg, field) * 1e9) <= 1000, (m.topic, stamp, getattr(msg, field))
        if m.msg_type == "sensor_msgs/msg/Image":  # a frame time t0_s + k/fps, to 1 us
            k = round(((stamp - origin) * 1e-9 - cam.t0_s) * cam.fps)
            assert abs((stamp - origin) - (cam.t0_s + k / cam.fps) * 1e9) <= 1000
        if m.msg_type == "vibro_msgs/msg/DicFrame":
            dic_stamps[int(msg.frame_index)] = stamp
        checked[m.msg_type] = checked.get(m.msg_type, 0) + 1
    assert {"sensor_msgs/msg/Image", *DATA_TIME_FIELDS} <= set(checked), checked
    return dic_stamps


def test_graph_results_equal_the_offline_cli(reference_run: dict) -> None:
    run = reference_run
    bag, graph_stdout = run["bag"], run["graph_stdout"]
    # header stamps on the lab's wall clock: frame 0 at the start of the run (no start time in rig.yaml)
    _stamps_on_the_lab_clock(bag, run["wall_ns"], 0.3)
    assert "frames in 300 / tracked 300 / lost 0" in graph_stdout, graph_stdout
    a, b = run["analyze"], run["bag_doc"]
    assert len(a["impacts"]) >= 8 and len(a["impacts"]) == len(b["impacts"])
    for x, y in zip(a["impacts"], b["impacts"]):
        assert x["plate"] == y["plate"]
        assert abs(x["cor"] - y["cor"]) < 1e-6 and abs(x["t"] - y["t"]) < 1e-9
    for model in ("cor_model", "hertz_model"):
        assert abs(a["simulation"][model]["deviation"] - b["simulation"][model]["deviation"]) < 1e-6
    # the truth: every impact of this synthetic run has its own COR (per-plate law plus scatter), which the
    # graph must recover impact by impact; the fitted method's error on a clean DIC track is far below 0.01
    # (bench_fit: ~1e-4 without scatter; the scatter does not enter the estimate of one impact)
    truth = run["truth"]["impacts"]
    for est in b["impacts"]:
        nearest = min(truth, key=lambda i: abs(i["t"] - est["t"]))
        assert abs(nearest["t"] - est["t"]) < 1e-3, (est, nearest)
        assert abs(est["cor"] - nearest["cor"]) < 0.01, (est, nearest)


def test_graph_reports_a_dropped_frame_and_stamps_on_the_recordings_start(recording: Path, tmp_path: Path) -> None:
    # the recording's start on the wall clock is known (rig.yaml camera.start_time_unix_s): stamps use it
    rec = tmp_path / "rec"
    shutil.copytree(recording, rec)
    rig = yaml.safe_load((rec / "rig.yaml").read_text())
    rig["camera"]["start_time_unix_s"] = 1718000000.123456
    (rec / "rig.yaml").write_text(yaml.safe_dump(rig))
    frame0_ns = 1_718_000_000_123_456_000
    (rec / "frames" / "000150.png").unlink()
    (rec / "frames" / "000151.png").write_bytes(b"corrupt")
    graph = _vibro("graph", str(rec), "--bag", str(tmp_path / "bag"))
    assert graph.returncode == 0, graph.stdout + graph.stderr
    assert "frames in 300 / tracked 298 / lost 2" in graph.stdout
    assert "no image received" in graph.stdout
    # frame 0 exactly at the given time; the two lost frames are answered without a DIC result stamp
    stamps = _stamps_on_the_lab_clock(tmp_path / "bag", (frame0_ns, frame0_ns), 0.3)
    fps = float(rig["camera"]["fps"])
    assert abs(stamps[0] - frame0_ns) <= 1000 and abs(stamps[299] - (frame0_ns + 299 / fps * 1e9)) <= 1000


def test_graph_refuses_bad_input_before_starting(tmp_path: Path, recording: Path) -> None:
    res = _vibro("graph", str(tmp_path / "missing"), "--bag", str(tmp_path / "b"))
    assert res.returncode == 2 and "not a recording directory" in res.stderr and "Traceback" not in res.stderr
    (tmp_path / "b2").mkdir()
    res = _vibro("graph", str(recording), "--bag", str(tmp_path / "b2"))
    assert res.returncode == 2 and "already exists" in res.stderr


def test_replaying_a_bag_reproduces_its_results(reference_run: dict, tmp_path: Path) -> None:
    from vibro_ros.bags import read_custom_data

    bag = reference_run["bag"]
    replay = _vibro("replay", str(bag), "--out", str(tmp_path / "re"))
    assert replay.returncode == 0, replay.stdout + replay.stderr
    # the replay stamps on the original run's lab clock, identically (its frame 0 where the original's was)
    from vibro_io.rig import parse_rig

    custom = read_custom_data(bag)
    t0_s = parse_rig(yaml.safe_load(custom["vibro.rig_yaml"])).camera.t0_s
    frame0 = int(custom["vibro.time_origin_unix_ns"]) + round(t0_s * 1e9)
    stamps = _stamps_on_the_lab_clock(bag, (frame0, frame0), 0.3)
    assert _stamps_on_the_lab_clock(tmp_path / "re" / "bag", (frame0, frame0), 0.3) == stamps
    assert len(stamps) == 300
    assert "frames in 300 / tracked 300 / lost 0" in replay.stdout, replay.stdout
    a = reference_run["bag_doc"]
    b = json.loads((tmp_path / "re" / "results.json").read_text())
    # the same CDR frames through the same deterministic code: the same numbers
    assert len(a["impacts"]) == len(b["impacts"]) > 0
    assert all(abs(x["cor"] - y["cor"]) < 1e-9 for x, y in zip(a["impacts"], b["impacts"]))
    assert abs(a["simulation"]["cor_model"]["deviation"] - b["simulation"]["cor_model"]["deviation"]) < 1e-9
    # every node of both runs stopped cleanly: no Python traceback in any node's log
    logs = [*Path(f"{bag}.logs").glob("*.log"), *(tmp_path / "re").rglob("*.log")]
    assert logs
    for log in logs:
        assert "Traceback" not in log.read_text(), log


def test_replay_refuses_a_bag_without_a_rig(tmp_path: Path) -> None:
    from vibro_ros.bags import BagWriter

    w = BagWriter(tmp_path / "plain")
    w.add_topic("vibro/status", "vibro_msgs/msg/StreamStatus")
    w.close()
    res = _vibro("replay", str(tmp_path / "plain"))
    assert res.returncode == 2 and "holds no rig.yaml" in res.stderr and "Traceback" not in res.stderr


@pytest.mark.parametrize("command", ["graph", "replay"])
def test_graph_run_options_are_validated(command: str, tmp_path: Path) -> None:
    target = [str(tmp_path / "rec"), "--bag", str(tmp_path / "bag")] if command == "graph" else [str(tmp_path / "bag")]
    for option, value, expect in (("--respawn", "-1", "must be >= 0"), ("--timeout-s", "0", "must be > 0")):
        res = _vibro(command, *target, option, value, timeout=60)
        assert res.returncode == 2 and f"argument {option}: {expect}" in res.stderr and "Traceback" not in res.stderr
