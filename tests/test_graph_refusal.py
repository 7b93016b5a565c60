"""The graph refuses a run as ``vibro analyze`` does (vibro_fit.cross_checks in trajectory_fitter's final pass).

The shared reference run (conftest ``reference_run``: 300 synthetic frames, 22 Hz drive, asymmetric restitution)
is the unmodified case; its recording with rig.yaml excitation.frequency_hz 50 is the refused one (the case
tests/test_cross_checks.py gives analyze): the CORs measured against structure fits seeded at 50 Hz leave
[0, 1]. The graph must end with trajectory_fitter's refusal (exit code 2) naming the key, ``vibro results`` of
its bag must exit 2 with analyze's 'consistency' section and no COR table, and the unmodified run must not be
refused and keep analyze's CORs.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

VIBRO = [sys.executable, "-m", "vibro_app.cli"]
WRONG_HZ = 50.0
#: graph and analyze run the same cores on the same CDR-exact numbers (tests/test_bag_vs_analyze.py: 1e-9)
TOL = 1e-9


def _vibro(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([*VIBRO, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def wrong_frequency(reference_run, tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("refusal")
    rec = tmp / "rec"
    shutil.copytree(reference_run["rec"], rec)
    rig = yaml.safe_load((rec / "rig.yaml").read_text())
    assert rig["excitation"]["frequency_hz"] != WRONG_HZ
    rig["excitation"]["frequency_hz"] = WRONG_HZ
    (rec / "rig.yaml").write_text(yaml.safe_dump(rig, sort_keys=False))
    return rec


def test_wrong_excitation_frequency_refuses_the_graph_run_and_its_bag(wrong_frequency, ros_domain, tmp_path):
    bag = tmp_path / "bag"
    graph = _vibro("graph", str(wrong_frequency), "--bag", str(bag), "--domain-id", ros_domain,
                   "--timeout-s", "150")
    out = graph.stdout + graph.stderr
    assert graph.returncode == 2, out    # as vibro analyze and vibro results of the bag exit on this input
    # the run ends on the fitter's refusal, its log's line naming the key that is wrong
    failed = [line for line in graph.stdout.splitlines() if line.startswith("FAILED:")]
    assert any("trajectory_fitter exited with code 2" in line for line in failed), out
    assert "COR outside [0, 1]" in out and "excitation.frequency_hz" in out, out
    # the streamed previews are not printed as a result
    assert "COR table withheld" in graph.stdout and "COR mean" not in graph.stdout, out

    # the bag holds the streamed previews, some of them impossible: what the refusal keeps out of the document
    from vibro_app.bag_results import BagResults
    from vibro_ros import topics

    recorded = BagResults(bag)
    previews = [m.cor for m in recorded.streamed[topics.IMPACTS.name].values() if math.isfinite(m.cor)]
    assert previews and max(previews) > 1.0
    assert not recorded.final[topics.IMPACTS.name]
    assert recorded.finished_lost.get("impacts", 0) > 0  # the withheld impacts, counted lost

    res = _vibro("results", str(bag), "--out", str(tmp_path / "res"))
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vibro results: error:"), res.stderr
    assert "COR outside [0, 1]" in lines[0] and "excitation.frequency_hz" in lines[0]
    doc = json.loads((tmp_path / "res" / "results.json").read_text())
    assert doc["complete"] is False
    assert doc["impacts"] == []
    assert doc["cor_summary"]["top"]["n"] == doc["cor_summary"]["bottom"]["n"] == 0
    assert doc["consistency"]["refused"] is True
    assert "findings:" not in res.stdout  # the discrepancy analysis never ran: no 'the model explains' line

    # the same core as vibro analyze: analyze of the same recording refuses with the same finding (its own DIC,
    # not --track: dic.csv's 9 digits move the structure fits seeded at the wrong frequency by ~1e-6 in COR)
    an = tmp_path / "an"
    off = _vibro("analyze", str(wrong_frequency), "--out", str(an), "--no-progress", "--no-report")
    assert off.returncode == 2, off.stderr
    offline = json.loads((an / "results.json").read_text())["consistency"]
    assert [(f["check"], f["severity"], f["keys"]) for f in doc["consistency"]["findings"]] == \
        [(f["check"], f["severity"], f["keys"]) for f in offline["findings"]]
    (graph_finding,) = [f for f in doc["consistency"]["findings"] if f["check"] == "cor_outside_0_1"]
    (offline_finding,) = [f for f in offline["findings"] if f["check"] == "cor_outside_0_1"]
    assert graph_finding["keys"] == ["excitation.frequency_hz"]
    for got, want in zip(graph_finding["evidence"]["cor_against_recording_sine_range"],
                         offline_finding["evidence"]["cor_against_recording_sine_range"]):
        assert abs(got - want) <= TOL * max(1.0, abs(want))
    # the evidence is physical: against the recording's own sine the COR is back in [0, 1]
    lo, hi = graph_finding["evidence"]["cor_against_recording_sine_range"]
    assert 0.0 <= lo <= hi <= 1.0


def test_unmodified_recording_is_not_refused_and_keeps_analyzes_cors(reference_run):
    # no false refusal: the fixture's graph run exited 0 (asserted when it was made), its bag's document carries
    # the cross-checks that passed, and its CORs are analyze's
    doc, offline = reference_run["bag_doc"], reference_run["analyze"]
    assert "COR table withheld" not in reference_run["graph_stdout"]
    assert doc["consistency"]["refused"] is False
    assert not any(f["severity"] == "refuse" for f in doc["consistency"]["findings"])
    assert [f["check"] for f in doc["consistency"]["findings"]] == \
        [f["check"] for f in offline["consistency"]["findings"]]
    assert doc["complete"] is True
    assert len(doc["impacts"]) == len(offline["impacts"]) > 0
    for a, b in zip(offline["impacts"], doc["impacts"]):
        assert a["index"] == b["index"]
        if a["cor"] is None:
            assert b["cor"] is None
        else:
            assert abs(a["cor"] - b["cor"]) <= TOL * max(1.0, abs(a["cor"]))
            assert 0.0 <= a["cor"] <= 1.0


def test_a_ball_lost_in_most_frames_is_refused_alike_on_every_path(ros_domain, tmp_path):
    """A speckled ball that spins (2 rad/s) is lost after a few degrees: ``vibro analyze`` refuses its tracking;
    the graph's fitter and ``vibro results`` of the bag refuse the same track with the same words and exit code
    (before, the graph published 2 impacts from the 18 % of frames left, exit code 0)."""
    from vibro_sim.synth import SynthConfig, synthesize

    rec = tmp_path / "spinning"
    synthesize(rec, SynthConfig(frames=300, seed=1, accel=False, spin_rad_s=2.0), progress=False)
    analyzed = _vibro("analyze", str(rec), "--out", str(tmp_path / "out"), "--no-report", "--no-progress")
    assert analyzed.returncode == 2 and "tracking refused: ball lost" in analyzed.stderr, analyzed.stderr
    words = analyzed.stderr.split("tracking refused: ", 1)[1].splitlines()[0]
    assert "it spins" in words and "dic.ball_method: outline" in words
    bag = tmp_path / "bag"
    graph = _vibro("graph", str(rec), "--bag", str(bag), "--domain-id", ros_domain, "--timeout-s", "150")
    out = graph.stdout + graph.stderr
    assert graph.returncode == 2, out
    assert "trajectory_fitter exited with code 2" in out and words in out, out
    res = _vibro("results", str(bag))
    assert res.returncode == 2 and words in res.stderr, res.stderr
    doc = json.loads(res.stdout)
    assert doc["complete"] is False and doc["consistency"]["refused"] is True
    assert [f["check"] for f in doc["consistency"]["findings"]][0] == "tracking"
