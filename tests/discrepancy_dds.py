"""Run the ``discrepancy`` node in its own process, fed by tests/discrepancy_feeder.py, and collect what it
publishes on one topic with tests/ros_echo.py (three processes over DDS)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _start(*argv: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def feed_case(path: Path, sections: dict, track) -> Path:
    """Write the feeder's case file: the identification ``sections`` (structure, flights, impacts as in
    results.json, and its dic_bias when given: the fitter's StructureMotion carries it) and the DIC ``track``
    columns it needs."""
    cols = ("frame", "t_s", "ball_mm", "structure_mm")
    names = ("structure", "flights", "impacts", "dic_bias")
    path.write_text(json.dumps({"sections": {k: sections[k] for k in names if k in sections},
                                "track": {c: getattr(track, c).tolist() for c in cols}}))
    return path


@dataclass
class NodeRun:
    rows: list[dict]      # the messages received, as plain dicts
    node_err: str
    feeder_err: str
    node_returncode: int  # after SIGINT once the echo had its messages (or its 90 s)

    @property
    def logs(self) -> str:
        return f"node:\n{self.node_err}\nfeeder:\n{self.feeder_err}"


def run_discrepancy_node(case_file: Path, rig_file: Path, msg_type: str, topic: str, count: int) -> NodeRun:
    """Start the echo (``count`` messages of ``msg_type`` on ``topic``, 90 s at most), the node and the feeder,
    then stop them."""
    echo = _start(str(HERE / "ros_echo.py"), msg_type, topic, "--count", str(count), "--seconds", "90",
                  "--qos", "results")
    # the echo is the node's declared reader, as the node table makes the recorder: without it the node exits
    # as soon as its results are published, and an echo not yet matched by then never gets them
    node = _start("-m", "vibro_discrepancy.discrepancy_node", "--ros-args", "-p", f"rig_file:={rig_file}",
                  "-p", "readers:=[vibro_test_echo]")
    feeder = None
    try:
        assert echo.stdout.readline().strip() == "READY"
        feeder = _start(str(HERE / "discrepancy_feeder.py"), str(case_file), "--seconds", "60")
        out, _ = echo.communicate(timeout=120)
    finally:
        node.send_signal(signal.SIGINT)
        _, node_err = node.communicate(timeout=20)
        feeder_err = ""
        if feeder is not None:
            feeder.kill()
            feeder_err = feeder.communicate()[1]
        echo.kill()
    rows = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    return NodeRun(rows, node_err, feeder_err, node.returncode)
