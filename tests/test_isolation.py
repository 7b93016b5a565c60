"""Runs on a shared DDS domain (issue #16.5): two default `vibro graph` runs at once stay apart, and a
foreign publisher on a run's input stops the node that reads it and fails the run, naming the publisher.

Both runs of a test share one private domain chosen by the test (the `ros_domain` fixture), as two
users' runs with ROS_DOMAIN_ID unset share domain 0, without disturbing other test runs on this machine.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from vibro_sim.synth import SynthConfig, synthesize

HERE = Path(__file__).resolve().parent
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
#: Two distinct constant CORs (truth of the synthetic rig); a run that merged the other's frames would
#: give CORs of the wrong run or a blend, far outside the fitter's accuracy (bench_fit: ~1e-4; test_graph: 0.01).
TRUE_COR = {"a": 0.70, "b": 0.55}
COR_TOL = 0.01
#: an impact time from the graph against the truth (s)
T_TOL_S = 1e-3
IDENTITY = re.compile(r"run (r[0-9a-f]{7}): namespace (/\S+), ROS_DOMAIN_ID (\d+)")


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> dict[str, Path]:
    """Two 300-frame recordings with different phase (seed) and COR."""
    root = tmp_path_factory.mktemp("isolation")
    synthesize(root / "a", SynthConfig(frames=300, seed=11), progress=False)
    synthesize(root / "b", SynthConfig(frames=300, seed=12, effects={"asymmetric_restitution": {
        "cor_top": TRUE_COR["b"], "cor_bottom": TRUE_COR["b"], "cor_sigma": 0.0}}), progress=False)
    for name, rec in (("a", root / "a"), ("b", root / "b")):
        truth = json.loads(Path(f"{rec}.truth.json").read_text())
        assert {round(i["cor"], 9) for i in truth["impacts"]} == {TRUE_COR[name]}
    return {"a": root / "a", "b": root / "b"}


def _vibro(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=timeout)


def test_two_default_runs_on_one_domain_keep_their_own_results(recordings: dict[str, Path], tmp_path: Path,
                                                                ros_domain: str) -> None:
    env = dict(os.environ, ROS_DOMAIN_ID=ros_domain)  # the same domain for both, as two users' unset ROS_DOMAIN_ID
    runs = {name: subprocess.Popen([*VIBRO, "graph", str(rec), "--bag", str(tmp_path / f"bag_{name}"),
                                    "--timeout-s", "240"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                   text=True, env=env)
            for name, rec in recordings.items()}
    outs = {}
    try:
        for name, proc in runs.items():
            outs[name] = proc.communicate(timeout=300)
    finally:
        for proc in runs.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    idents = {}
    for name, proc in runs.items():
        out, err = outs[name]
        assert proc.returncode == 0, f"run {name}:\n{out}\n{err}"
        assert "frames in 300 / tracked 300 / lost 0" in out, out
        m = IDENTITY.search(out)
        assert m and m.group(3) == ros_domain, out  # the summary says which namespace and domain were used
        idents[name] = m.groups()
    assert idents["a"][0] != idents["b"][0] and idents["a"][1] != idents["b"][1]

    # each bag's impacts are those of its own recording's truth, impact by impact: the same count over the
    # fitted span, times within 1 ms (test_graph's tolerance against the truth) and the recording's own COR.
    # A run that took the other's frames, or a blend, gives CORs of the wrong run (0.70 vs 0.55, 15x the
    # tolerance) or impacts where its truth has none.
    truths = {name: json.loads(Path(f"{rec}.truth.json").read_text())["impacts"] for name, rec in recordings.items()}
    for name, rec in recordings.items():
        extracted = _vibro("results", str(tmp_path / f"bag_{name}"), "--out", str(tmp_path / f"res_{name}"))
        assert extracted.returncode == 0, extracted.stderr
        b = json.loads((tmp_path / f"res_{name}" / "results.json").read_text())["impacts"]
        t_first, t_last = b[0]["t"] if b else 0.0, b[-1]["t"] if b else 0.0
        inside = [i for i in truths[name] if t_first - T_TOL_S <= i["t"] <= t_last + T_TOL_S]
        assert len(b) >= 8 and len(b) == len(inside), (name, len(b), len(inside))
        for est, true in zip(b, inside):
            assert abs(est["t"] - true["t"]) < T_TOL_S, (name, est, true)
            assert abs(est["cor"] - TRUE_COR[name]) < COR_TOL, (name, est)
        print(f"run {name} ({idents[name][1]}, domain {idents[name][2]}): {len(b)} impacts, mean COR "
              f"{sum(i['cor'] for i in b) / len(b):.4f} (truth {TRUE_COR[name]}), max |t - truth| "
              f"{max(abs(x['t'] - y['t']) for x, y in zip(b, inside)) * 1e3:.3f} ms")


def _params(tmp: Path, rate_hz: float) -> Path:
    from vibro_bringup.graph_spec import default_params_file, params_file_key

    data = yaml.safe_load(default_params_file().read_text())
    data[params_file_key("frame_source")]["ros__parameters"]["rate_hz"] = rate_hz
    path = tmp / "params.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_foreign_frames_publisher_stops_the_tracker_and_fails_the_run(recordings: dict[str, Path],
                                                                         tmp_path: Path, ros_domain: str) -> None:
    rec = recordings["a"]
    cam = yaml.safe_load((rec / "rig.yaml").read_text())["camera"]
    namespace = f"/vibro_intrusion_{os.getpid()}"
    # 60 frames/s: 5 s of streaming, so the foreign camera joins mid-run
    graph = subprocess.Popen([*VIBRO, "graph", str(rec), "--bag", str(tmp_path / "bag"), "--namespace", namespace,
                              "--params", str(_params(tmp_path, 60.0)), "--timeout-s", "120"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    intruder = None
    try:
        source_log = tmp_path / "bag.logs" / "frame_source.log"
        deadline = time.monotonic() + 120
        while "streaming:" not in (source_log.read_text() if source_log.exists() else ""):
            if time.monotonic() > deadline or graph.poll() is not None:
                out, err = graph.communicate()
                pytest.fail(f"frame_source never started streaming (exit {graph.returncode})\n{out}\n{err}")
            time.sleep(0.05)
        intruder = subprocess.Popen([sys.executable, str(HERE / "ros_intruder.py"), namespace, "--t0",
                                     str(cam.get("t0_s", 0.0)), "--fps", str(cam["fps"]), "--frame", "5"],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out, err = graph.communicate(timeout=150)
    finally:
        if graph.poll() is None:
            graph.kill()
            graph.communicate()
        if intruder is not None:
            intruder.kill()
            intruder.communicate()
    assert graph.returncode != 0, out + err
    # the run names the node that stopped, why, and the foreign publisher; no merged result is reported
    assert re.search(rf"dic_tracker exited with code 2;.*{namespace}/dic_tracker: vibro/frames: .*"
                     rf"{namespace}/intruder_camera", err, re.S), err
    assert "restarted" not in err  # refusing foreign input is not a crash: no respawn
    tracker_log = (tmp_path / "bag.logs" / "dic_tracker.log").read_text()
    assert "Traceback" not in tracker_log and "intruder_camera" in tracker_log, tracker_log


@pytest.mark.parametrize("command", ["graph", "replay"])
def test_a_bad_namespace_is_refused_before_anything_starts(command: str, tmp_path: Path) -> None:
    target = [str(tmp_path / "rec"), "--bag", str(tmp_path / "bag")] if command == "graph" else [str(tmp_path / "bag")]
    res = _vibro(command, *target, "--namespace", "/lab/1run", timeout=60)
    assert res.returncode == 2 and "argument --namespace: '/lab/1run' is not a ROS namespace" in res.stderr
    assert "Traceback" not in res.stderr and not (tmp_path / "bag").exists()
