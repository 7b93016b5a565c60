"""How ``vibro campaign`` schedules its runs (src/vibro_app/vibro_app/campaign/engine.py): longest first with Dask
priorities, the cluster started only when some run surely needs work (while the others are fingerprinted), and
the campaign rows made as runs finish equal to rows made the old way, after the last task.

The scheduling test runs fake tasks on an in-process Dask cluster of one worker thread (no analysis); the others
analyse three short synthetic recordings of different lengths on a local cluster of one worker process.
"""

from __future__ import annotations

import json
import os
import subprocess
import threading
from pathlib import Path

import pytest
import yaml
from conftest import REPO

import vibro_app.campaign.engine as engine
import vibro_dic.cluster as cluster_mod
from vibro_app.campaign.summary import flag_disagreeing, orientation_groups, run_summary

VIBRO = str(REPO / "vibro")
#: run name -> frames: sorted by name, the lengths are not in order (longest first is r2, r3, r1)
LENGTHS = {"r1": 140, "r2": 200, "r3": 170}
#: the keys of a task's record (task.analyze_run, or a resumed run's); run_summary adds the rest of a row
RECORD_KEYS = ("name", "recording", "status", "reason", "resumed", "warnings", "task_s", "worker_pid", "traceback")


def _bytes_of(recording: Path) -> int:
    """The recording's files' total size, rig.yaml left out (the engine's cost estimate), counted here."""
    return sum((Path(d) / f).stat().st_size for d, _, files in os.walk(recording) for f in files
               if Path(d) / f != recording / "rig.yaml")


class _InProcessClient:
    """Stands in for :class:`vibro_dic.cluster.BackgroundClient`: an in-process Dask cluster (one worker, one
    thread, worker-saturation 1.0 as the campaign's local cluster has) whose ``submit`` calls are recorded."""

    made: list["_InProcessClient"] = []

    def __init__(self, workers=None, scheduler=None, *, list_scheduling=False):
        import dask
        from distributed import Client, LocalCluster

        with dask.config.set({"distributed.scheduler.worker-saturation": 1.0}):
            self.cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None)
        self.client = Client(self.cluster)
        self.submitted: list[tuple[str, int]] = []  # (run name, priority) in submission order
        submit = self.client.submit

        def recording_submit(fn, *args, **kwargs):
            self.submitted.append((args[0], kwargs.get("priority", 0)))
            return submit(fn, *args, **kwargs)

        self.client.submit = recording_submit
        self.start_s = 0.0
        self.made.append(self)

    def result(self):
        return self.client

    def close(self) -> None:
        self.client.close()
        self.cluster.close()


_STARTED: list[str] = []  # the fake tasks' names in the order they started (in-process worker thread)


def _fake_task(name, recording, run_dir, options, fingerprint, version) -> dict:
    """Stands in for task.analyze_run: notes that it started, takes 50 ms, reads nothing."""
    _STARTED.append(name)
    threading.Event().wait(0.05)
    return {"name": name, "recording": recording, "status": "failed", "reason": "fake task", "warnings": [],
            "task_s": 0.05}


def test_runs_submitted_longest_first(tmp_path: Path, monkeypatch) -> None:
    # four "recordings" whose only content is a blob of a known size (the fake task reads nothing)
    sizes = {"a": 1000, "b": 4000, "c": 2000, "d": 3000}
    for name, size in sizes.items():
        (tmp_path / "sweep" / name / "frames").mkdir(parents=True)
        (tmp_path / "sweep" / name / "rig.yaml").write_text("{}\n")
        (tmp_path / "sweep" / name / "frames" / "blob.bin").write_bytes(b"x" * size)
    _STARTED.clear()
    _InProcessClient.made.clear()
    monkeypatch.setattr(cluster_mod, "BackgroundClient", _InProcessClient)
    monkeypatch.setattr(engine, "analyze_run", _fake_task)
    doc = engine.run_campaign(tmp_path / "sweep", tmp_path / "out")
    expected = sorted(sizes, key=lambda n: -sizes[n])  # b d c a
    [made] = _InProcessClient.made
    assert [name for name, _ in made.submitted] == expected
    priorities = [p for _, p in made.submitted]
    assert priorities == sorted(priorities, reverse=True) and len(set(priorities)) == len(priorities)
    assert _STARTED == expected  # one worker thread: Dask ran them in priority order
    schedule = doc["timing"]["schedule"]["runs"]
    assert [r["name"] for r in schedule] == expected
    assert {r["name"]: r["cost_bytes"] for r in schedule} == {n: _bytes_of(tmp_path / "sweep" / n) for n in sizes}
    assert [r["name"] for r in doc["runs"]] == sorted(sizes)  # the report keeps the runs' own order
    assert all(r["status"] == "failed" and r["reason"] == "fake task" for r in doc["runs"])


def test_longest_first_ties_by_name() -> None:
    from vibro_app.campaign.runs import RunSpec

    todo = [(RunSpec(n, Path(n)), Path(n), "fp", cost) for n, cost in (("z", 5), ("b", 7), ("a", 5), ("c", 1))]
    assert [t[0].name for t in engine.longest_first(todo)] == ["b", "a", "z", "c"]


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("schedule") / "sweep"
    procs = [subprocess.Popen([VIBRO, "synth", "--out", str(root / name), "--frames", str(frames), "--seed",
                               str(20 + i), "--cor-scatter", "0.01", "--no-progress"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for i, (name, frames) in enumerate(LENGTHS.items())]
    for p in procs:
        out, _ = p.communicate(timeout=300)
        assert p.returncode == 0, out
    return root


@pytest.fixture(scope="module")
def campaign(recordings: Path, tmp_path_factory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("schedule_out") / "out"
    return engine.run_campaign(recordings, out, workers=1), out


def _rows_the_old_way(doc: dict, out: Path) -> list[dict]:
    """The campaign rows rebuilt from the runs' records as the engine made them before (all after the last task,
    from results.json and rig.yaml), through JSON like campaign.json."""
    rows = []
    for row in doc["runs"]:
        record = {k: row[k] for k in RECORD_KEYS if k in row}
        rebuilt = run_summary(record, out / row["name"])
        rebuilt.setdefault("resumed", False)
        rows.append(rebuilt)
    flag_disagreeing(rows)
    return json.loads(json.dumps(rows))


def test_campaign_rows_unchanged_and_longest_first(campaign, recordings: Path) -> None:
    doc, out = campaign
    assert doc["summary"]["n_ok"] == 3, doc["summary"]
    schedule = doc["timing"]["schedule"]["runs"]
    assert [r["name"] for r in schedule] == ["r2", "r3", "r1"]  # by length: 200, 170, 140 frames
    assert {r["name"]: r["cost_bytes"] for r in schedule} == {n: _bytes_of(recordings / n) for n in LENGTHS}
    on_disk = json.loads((out / "campaign.json").read_text())
    assert on_disk["runs"] == _rows_the_old_way(on_disk, out)
    assert on_disk["orientation"] == json.loads(json.dumps(orientation_groups(on_disk["runs"])))
    # and against the runs' own files, read here
    for row in on_disk["runs"]:
        results = json.loads((out / row["name"] / "results.json").read_text())
        rig = yaml.safe_load((recordings / row["name"] / "rig.yaml").read_text())
        assert row["excitation"]["frequency_hz"] == rig["excitation"]["frequency_hz"]
        assert row["n_impacts"] == len(results["impacts"]) and row["n_impacts"] > 0
        for plate in ("top", "bottom"):
            assert row["cor"][plate]["mean"] == results["cor_summary"][plate]["mean"]
            assert row["cor"][plate]["n"] == results["cor_summary"][plate]["n"]
        assert [i["cor"] for i in row["impacts"]] == [i["cor"] for i in results["impacts"]]
    timing = doc["timing"]
    assert timing["cluster_start_s"] > 0 and timing["n_workers"] == 1
    assert set(timing["after_tasks"]) >= {"figures_s", "report_html_s", "cluster_close_wait_s"}


def test_up_to_date_campaign_starts_no_cluster(campaign, recordings: Path, monkeypatch) -> None:
    doc, out = campaign

    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster was started for a campaign with nothing to do")

    monkeypatch.setattr(cluster_mod, "BackgroundClient", no_cluster)
    again = engine.run_campaign(recordings, out, workers=1)
    assert again["timing"]["cluster_start_s"] is None and again["summary"]["n_resumed"] == 3
    for old, new in zip(doc["runs"], again["runs"]):
        assert new["resumed"] and new["cor"] == old["cor"] and new["impacts"] == old["impacts"]


def test_cluster_started_only_once_a_run_needs_work(campaign, recordings: Path, monkeypatch) -> None:
    """Every run has its stored fingerprint: the cluster starts after the fingerprint that differs (r1's, the
    first by name), not before; only that run is redone."""
    doc, out = campaign
    fingerprinted: list[str] = []
    started_after: list[int] = []
    real_fingerprint = engine.input_fingerprint

    def counting_fingerprint(recording, *args, **kwargs):
        fingerprinted.append(Path(recording).name)
        return real_fingerprint(recording, *args, **kwargs)

    class Recorded(_InProcessClient):
        def __init__(self, *args, **kwargs):
            started_after.append(len(fingerprinted))
            super().__init__(*args, **kwargs)

    frame = recordings / "r1" / "frames" / "000003.png"
    st = frame.stat()
    os.utime(frame, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    monkeypatch.setattr(engine, "input_fingerprint", counting_fingerprint)
    monkeypatch.setattr(cluster_mod, "BackgroundClient", Recorded)
    again = engine.run_campaign(recordings, out, workers=1)
    assert started_after == [1] and fingerprinted == ["r1", "r2", "r3"]
    assert [r["resumed"] for r in again["runs"]] == [False, True, True]
    assert again["summary"]["n_ok"] == 3
    old, new = doc["runs"][0], again["runs"][0]
    assert new["n_impacts"] == old["n_impacts"]  # the same inputs, redone (here in a thread of this process)
    for plate in ("top", "bottom"):
        assert new["cor"][plate]["mean"] == pytest.approx(old["cor"][plate]["mean"], rel=1e-9)
