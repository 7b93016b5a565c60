"""The whole node graph in separate processes: vibro graph vs vibro analyze, bag results, lost frames."""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from vibro_sim.synth import SynthConfig, synthesize

VIBRO = [sys.executable, "-m", "vibro_bringup.cli"]


def _vibro(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(101, 200)))
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=timeout, env=env)


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("graph") / "rec"
    synthesize(out, SynthConfig(frames=300, seed=11), progress=False)
    return out


def test_graph_results_equal_the_offline_cli(recording: Path, tmp_path: Path) -> None:
    bag = tmp_path / "bags" / "run"
    graph = _vibro("graph", str(recording), "--bag", str(bag))
    assert graph.returncode == 0, graph.stdout + graph.stderr
    assert "frames in 300 / tracked 300 / lost 0" in graph.stdout, graph.stdout
    offline = _vibro("analyze", str(recording), "--out", str(tmp_path / "an"), "--no-progress", "--no-report")
    assert offline.returncode == 0, offline.stderr
    extracted = _vibro("results", str(bag), "--out", str(tmp_path / "bagres"))
    assert extracted.returncode == 0, extracted.stderr
    a = json.loads((tmp_path / "an" / "results.json").read_text())
    b = json.loads((tmp_path / "bagres" / "results.json").read_text())
    assert len(a["impacts"]) >= 8 and len(a["impacts"]) == len(b["impacts"])
    for x, y in zip(a["impacts"], b["impacts"]):
        assert x["plate"] == y["plate"]
        assert abs(x["cor"] - y["cor"]) < 1e-6 and abs(x["t"] - y["t"]) < 1e-9
    for model in ("cor_model", "hertz_model"):
        assert abs(a["simulation"][model]["deviation"] - b["simulation"][model]["deviation"]) < 1e-6
    # the truth: this synthetic run has one constant COR, which the graph must recover; the fitted
    # method's error on a noise-free-ish DIC track is far below 0.01 (bench_fit: ~1e-4)
    truth = json.loads(Path(str(recording) + ".truth.json").read_text())
    true_cors = {round(i["cor"], 9) for i in truth["impacts"]}
    assert len(true_cors) == 1
    true_cor = true_cors.pop()
    assert all(abs(i["cor"] - true_cor) < 0.01 for i in b["impacts"])


def test_graph_reports_a_dropped_frame(recording: Path, tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    shutil.copytree(recording, rec)
    (rec / "frames" / "000150.png").unlink()
    (rec / "frames" / "000151.png").write_bytes(b"corrupt")
    graph = _vibro("graph", str(rec), "--bag", str(tmp_path / "bag"))
    assert graph.returncode == 0, graph.stdout + graph.stderr
    assert "frames in 300 / tracked 298 / lost 2" in graph.stdout
    assert "no image received" in graph.stdout


def test_graph_refuses_bad_input_before_starting(tmp_path: Path, recording: Path) -> None:
    res = _vibro("graph", str(tmp_path / "missing"), "--bag", str(tmp_path / "b"))
    assert res.returncode == 2 and "not a recording directory" in res.stderr and "Traceback" not in res.stderr
    (tmp_path / "b2").mkdir()
    res = _vibro("graph", str(recording), "--bag", str(tmp_path / "b2"))
    assert res.returncode == 2 and "already exists" in res.stderr


def test_replaying_a_bag_reproduces_its_results(recording: Path, tmp_path: Path) -> None:
    bag = tmp_path / "orig"
    orig = _vibro("graph", str(recording), "--bag", str(bag), "--timeout-s", "150")
    assert orig.returncode == 0, orig.stdout + orig.stderr
    replay = _vibro("replay", str(bag), "--out", str(tmp_path / "re"))
    assert replay.returncode == 0, replay.stdout + replay.stderr
    assert "frames in 300 / tracked 300 / lost 0" in replay.stdout, replay.stdout
    assert _vibro("results", str(bag), "--out", str(tmp_path / "orig_res")).returncode == 0
    a = json.loads((tmp_path / "orig_res" / "results.json").read_text())
    b = json.loads((tmp_path / "re" / "results.json").read_text())
    # the same CDR frames through the same deterministic code: the same numbers
    assert len(a["impacts"]) == len(b["impacts"]) > 0
    assert all(abs(x["cor"] - y["cor"]) < 1e-9 for x, y in zip(a["impacts"], b["impacts"]))
    assert abs(a["simulation"]["cor_model"]["deviation"] - b["simulation"]["cor_model"]["deviation"]) < 1e-9
    # every node of both runs stopped cleanly: no Python traceback in any node's log
    for log in [*(tmp_path / "orig.logs").glob("*.log"), *(tmp_path / "re").rglob("*.log")]:
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
