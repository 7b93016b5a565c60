"""Issue 39: an unknown rig.yaml key is said once per run, not once per node (vibro_io.rig.RIG_CHECKED_ENV).

A lab that adds its own note to rig.yaml (a key vibro does not know and that misspells none it knows) reads one
warning; before, every node of the graph read the file and said it again (9 times among ros2 launch's output).
The supervisor (``vibro graph``, the launch file) reads the rig.yaml first and says its warnings; the nodes it
starts get the file's digest in their environment and say them at debug level only. A node started by hand
(``ros2 run``), or one given another file, still says them. A misspelt key is refused everywhere
(tests/test_io_rig.py).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import launch_api_double as L

from vibro_io.rig import RIG_CHECKED_ENV, load_rig, rig_checked_environment

NOTE = "operator_note: shaker 2 after its service\n"
WARNING = "unknown key 'operator_note' ignored"


def _rig_with_note(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    with open(dst / "rig.yaml", "a", encoding="utf-8") as f:
        f.write(NOTE)
    return dst


def _load_in_child(rig_yaml: Path, env: dict[str, str]) -> str:
    """stderr of a fresh process that loads ``rig_yaml`` as a node does, with ``env`` over this one's."""
    code = f"from vibro_io.rig import load_rig; load_rig({str(rig_yaml)!r})"
    run = subprocess.run([sys.executable, "-c", code], env={**os.environ, **env}, capture_output=True, text=True,
                         timeout=60, check=True)
    return run.stderr


def test_said_once_per_process(tiny_recording: Path, tmp_path: Path, caplog) -> None:
    rec = _rig_with_note(tiny_recording, tmp_path / "rec")
    for _ in range(3):
        load_rig(rec / "rig.yaml")
    assert caplog.text.count(WARNING) == 1


def test_a_node_started_by_the_supervisor_does_not_repeat_it(tiny_recording: Path, tmp_path: Path) -> None:
    rec = _rig_with_note(tiny_recording, tmp_path / "rec")
    checked = rig_checked_environment(rec / "rig.yaml")
    assert checked[RIG_CHECKED_ENV]
    assert WARNING in _load_in_child(rec / "rig.yaml", {RIG_CHECKED_ENV: ""})     # ros2 run by hand: said
    assert WARNING not in _load_in_child(rec / "rig.yaml", checked)               # the supervisor said it
    # the file changed since the supervisor read it: its warnings are this file's, said again
    with open(rec / "rig.yaml", "a", encoding="utf-8") as f:
        f.write("operator_shift: night\n")
    said = _load_in_child(rec / "rig.yaml", checked)
    assert WARNING in said and "operator_shift" in said


def test_the_launch_file_gives_every_node_the_checked_rig(tiny_recording: Path, tmp_path: Path) -> None:
    rec = _rig_with_note(tiny_recording, tmp_path / "rec")
    nodes = L.nodes_and_handlers(L.run_opaque(L.load_launch_file(), recording=str(rec)))
    assert nodes
    expected = rig_checked_environment(rec / "rig.yaml")
    assert {name: node.additional_env for name, (node, _) in nodes.items()} == {name: expected for name in nodes}


def test_vibro_graph_says_it_once(tiny_recording: Path, tmp_path: Path, ros_domain: str) -> None:
    """The real graph: every node a process of its own reading the rig.yaml; the warning is in vibro graph's
    output once and in no node's log (the 5-frame recording ends the run incomplete: exit 1, not what is tested)."""
    rec = _rig_with_note(tiny_recording, tmp_path / "rec")
    run = subprocess.run([sys.executable, "-m", "vibro_app.cli", "graph", str(rec), "--bag", str(tmp_path / "bag"),
                          "--domain-id", ros_domain], capture_output=True, text=True, timeout=240)
    logs = sorted((tmp_path / "bag.logs").glob("*.log"))
    assert len(logs) >= 5, run.stdout + run.stderr                     # the nodes did run and log
    assert (run.stdout + run.stderr).count(WARNING) == 1
    assert [p.name for p in logs if WARNING in p.read_text()] == []
