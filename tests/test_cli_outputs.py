"""Outputs of every writing subcommand: a non-empty --out is refused (exit 2, nothing touched), --overwrite
replaces only the command's own files (and refuses when anything else is there), bad --out paths are one
line on stderr, files are written atomically, --domain-id is checked by argparse."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from vibro_app.cli import main
from vibro_io.outputs import TEMP_MARK, OutputError, atomic_open, atomic_write_text, prepare_output_dir
from vibro_model.errors import RecordingError

REPO = Path(__file__).resolve().parents[1]
VIBRO = [sys.executable, "-m", "vibro_app.cli"]
ANALYZE_FIGURES = ("displacements.png", "cor_per_impact.png", "report.html")


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file under ``folder``: relative path -> (content, mtime_ns)."""
    return {p.relative_to(folder).as_posix(): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(folder.rglob("*")) if p.is_file()}


def temp_leftovers(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if TEMP_MARK in p.name]


def refused(capsys, argv: list[str]) -> str:
    """Run ``vibro argv`` in-process; assert exit 2 and a one-line error without a traceback; return it."""
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> tuple[Path, Path]:
    """A recording folder (rig.yaml, accel.csv) and a dic.csv of an exact COR-model motion (no frames:
    analyze runs with --track, so no DIC)."""
    from vibro_fit.identify import track_rows
    from vibro_fit.synthetic import accel_signals, paper_rig, sample_track, simulate
    from vibro_io.accel import write_accel
    from vibro_io.dictrack import write_dic_csv
    from vibro_io.rig import write_rig

    rec = tmp_path_factory.mktemp("outputs") / "rec"
    rec.mkdir()
    rig = paper_rig(accelerometers=True)
    write_rig(rig, rec / "rig.yaml")
    truth = simulate(amplitude_m=3e-3, duration_s=0.3, cor_jitter=0.03, seed=9)
    write_dic_csv(rec.parent / "dic.csv", track_rows(sample_track(truth, n_frames=300, noise_mm=0.0005)))
    write_accel(rec / "accel.csv", accel_signals(truth, duration_s=0.3, offset_s=0.003), rig.accelerometers)
    return rec, rec.parent / "dic.csv"


@pytest.fixture(scope="module")
def analyzed(recording) -> Path:
    """A complete earlier 'vibro analyze' output folder (figures, report)."""
    rec, dic = recording
    out = rec.parent / "analysis"
    assert main(["analyze", str(rec), "--out", str(out), "--track", str(dic), "--no-progress"]) == 0
    for name in ANALYZE_FIGURES + ("results.json", "flights.csv", "impacts.csv"):
        assert (out / name).is_file(), name
    return out


@pytest.fixture
def previous(analyzed: Path, tmp_path: Path) -> Path:
    """A private copy of the earlier analyze output, with a results.json marked as stale."""
    out = tmp_path / "an"
    shutil.copytree(analyzed, out)
    (out / "results.json").write_text('{"stale": true}\n')
    return out


@pytest.fixture
def track_csv(recording) -> Path:
    return recording[1]


@pytest.fixture
def rec(recording) -> Path:
    return recording[0]


# --- vibro analyze ---------------------------------------------------------------------------------------

def test_analyze_refuses_a_non_empty_folder_and_touches_nothing(rec, previous, track_csv, capsys):
    before = snapshot(previous)
    err = refused(capsys, ["analyze", str(rec), "--out", str(previous), "--track", str(track_csv),
                           "--no-progress"])
    assert str(previous) in err and "--overwrite" in err
    assert snapshot(previous) == before


def test_analyze_overwrite_removes_the_stale_outputs(rec, previous, track_csv, capsys):
    # the earlier run wrote figures and a report (and a DIC run writes dic.csv); this one writes no report:
    # none of the earlier files may survive beside the new results.json
    (previous / "dic.csv").write_text("stale\n")
    assert main(["analyze", str(rec), "--out", str(previous), "--track", str(track_csv), "--no-progress",
                 "--no-report", "--overwrite"]) == 0
    doc = json.loads((previous / "results.json").read_text())
    assert doc["schema"] == "vibro.results/1" and "stale" not in doc
    assert sorted(p.name for p in previous.iterdir()) == ["flights.csv", "impacts.csv", "results.json"]


def test_analyze_overwrite_never_deletes_a_user_file(rec, previous, track_csv, capsys):
    (previous / "notes.txt").write_text("my notes")
    before = snapshot(previous)
    err = refused(capsys, ["analyze", str(rec), "--out", str(previous), "--track", str(track_csv),
                           "--no-progress", "--overwrite"])
    assert "notes.txt" in err
    assert snapshot(previous) == before


def test_analyze_keeps_its_input_track_in_the_output_folder(rec, track_csv, tmp_path, capsys):
    # vibro track rec --out DIR; vibro analyze rec --track DIR/dic.csv --out DIR: the input is not "stale"
    out = tmp_path / "work"
    out.mkdir()
    shutil.copy(track_csv, out / "dic.csv")
    before = (out / "dic.csv").read_bytes()
    assert main(["analyze", str(rec), "--out", str(out), "--track", str(out / "dic.csv"), "--no-progress",
                 "--no-report"]) == 0
    assert (out / "dic.csv").read_bytes() == before and (out / "results.json").is_file()


@pytest.mark.parametrize("command", ["analyze", "track"])
def test_bad_out_paths_are_one_line(command, tiny_recording, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for out, reason in (("/proc/x", "cannot create"), (str(a_file), "not a folder")):
        err = refused(capsys, [command, str(tiny_recording), "--out", out, "--no-progress"])
        assert out in err and reason in err, err
    assert a_file.read_text() == "x"


def test_bad_out_path_through_the_entry_point(tiny_recording):
    res = subprocess.run([*VIBRO, "analyze", str(tiny_recording), "--out", "/proc/x", "--no-progress"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert res.stderr == "vibro analyze: error: /proc/x: cannot create the folder (No such file or directory)\n"


# --- vibro track -----------------------------------------------------------------------------------------

def test_track_refuses_then_overwrites_its_own_dic_csv(tiny_recording, tmp_path, capsys):
    out = tmp_path / "t"
    out.mkdir()
    (out / "dic.csv").write_text("stale\n")
    before = snapshot(out)
    refused(capsys, ["track", str(tiny_recording), "--out", str(out), "--no-progress"])
    assert snapshot(out) == before
    assert main(["track", str(tiny_recording), "--out", str(out), "--no-progress", "--overwrite"]) == 0
    from vibro_io.dictrack import read_dic_csv

    assert len(read_dic_csv(out / "dic.csv")) == 5  # the committed recording's 5 frames
    (out / "results.json").write_text("{}")  # not something vibro track writes
    before = snapshot(out)
    assert "results.json" in refused(capsys, ["track", str(tiny_recording), "--out", str(out), "--no-progress",
                                              "--overwrite"])
    assert snapshot(out) == before


def test_track_into_the_recording_folder_is_refused(tiny_recording, tmp_path, capsys):
    rec = tmp_path / "rec"
    shutil.copytree(tiny_recording, rec)
    before = snapshot(rec)
    refused(capsys, ["track", str(rec), "--out", str(rec), "--no-progress", "--overwrite"])
    assert snapshot(rec) == before


# --- vibro fit / summary ---------------------------------------------------------------------------------

def test_fit_writes_beside_its_input_then_needs_overwrite(rec, track_csv, tmp_path, capsys):
    work = tmp_path / "w"
    work.mkdir()
    shutil.copy(track_csv, work / "dic.csv")
    argv = ["fit", str(work / "dic.csv"), "--rig", str(rec / "rig.yaml"), "--out", str(work)]
    assert main(argv) == 0  # README: vibro fit DIR/dic.csv --out DIR
    assert {"results.json", "flights.csv", "impacts.csv", "dic.csv"} == {p.name for p in work.iterdir()}
    before = snapshot(work)
    refused(capsys, argv)
    assert snapshot(work) == before
    # an interrupted earlier write left a temporary file: --overwrite removes it with the earlier results
    leftover = work / f".results.json.abcd1234{TEMP_MARK}"
    leftover.write_text('{"half": ')
    (work / "results.json").write_text('{"stale": true}')
    assert main(argv + ["--overwrite"]) == 0
    assert "stale" not in json.loads((work / "results.json").read_text())
    assert not leftover.exists() and (work / "dic.csv").read_bytes() == before["dic.csv"][0]


def test_summary_refuses_an_existing_figure(analyzed, tmp_path, capsys):
    png = tmp_path / "fig14.png"
    argv = ["summary", str(analyzed / "results.json"), "--out", str(png)]
    assert main(argv) == 0 and png.is_file() and png.with_suffix(".csv").is_file()
    before = snapshot(tmp_path)
    refused(capsys, argv)
    assert snapshot(tmp_path) == before
    assert main(argv + ["--overwrite"]) == 0
    assert png.stat().st_mtime_ns > before["fig14.png"][1]
    assert "/proc/x.png" in refused(capsys, ["summary", str(analyzed / "results.json"), "--out", "/proc/x.png"])
    assert ".png" in refused(capsys, ["summary", str(analyzed / "results.json"), "--out", str(tmp_path / "fig")])
    assert not temp_leftovers(tmp_path)


def test_noise_json_refuses_an_existing_file(tmp_path, capsys):
    from vibro_sim.synth import SynthConfig, synthesize

    still = tmp_path / "still"
    synthesize(still, SynthConfig(frames=40, still=True, accel=False, seed=2), progress=False)
    out = tmp_path / "noise.json"
    out.write_text("mine")
    refused(capsys, ["noise", str(still), "--json", str(out), "--no-progress"])
    assert out.read_text() == "mine"
    assert main(["noise", str(still), "--json", str(out), "--no-progress", "--overwrite"]) == 0
    assert json.loads(out.read_text())["n_frames"] == 40


# --- vibro synth -----------------------------------------------------------------------------------------

def test_synth_overwrite_replaces_a_recording_but_never_user_files(tmp_path, capsys):
    rec = tmp_path / "r"
    argv = ["synth", "--out", str(rec), "--frames", "12", "--no-progress"]
    assert main(argv) == 0
    truth = tmp_path / "r.truth.json"
    before = snapshot(tmp_path)
    refused(capsys, argv + ["--frames", "10"])
    assert snapshot(tmp_path) == before
    assert main(argv[:-2] + ["10", "--no-progress", "--overwrite"]) == 0
    assert len(list((rec / "frames").iterdir())) == 10  # no stale frames 10 and 11
    assert len(json.loads(truth.read_text())["frames"]["t_s"]) == 10
    (rec / "frames" / "notes.txt").write_text("mine")
    before = snapshot(tmp_path)
    assert "frames/" in refused(capsys, argv + ["--overwrite"])
    assert snapshot(tmp_path) == before


def test_synth_overwrite_of_a_home_like_folder_is_refused(tmp_path, capsys):
    # the old --overwrite removed the whole folder (shutil.rmtree), whatever it held
    home = tmp_path / "home"
    (home / "documents").mkdir(parents=True)
    (home / "documents" / "thesis.tex").write_text("years of work")
    refused(capsys, ["synth", "--out", str(home), "--frames", "10", "--no-progress", "--overwrite"])
    assert (home / "documents" / "thesis.tex").read_text() == "years of work"


# --- vibro results / replay / graph: refusals before any node starts -------------------------------------

RIG_YAML = (REPO / "tests" / "fixtures" / "tiny_recording" / "rig.yaml")


@pytest.fixture(scope="module")
def result_bag(tmp_path_factory) -> Path:
    """A real MCAP bag of a complete (if impact-free) run: the fitter's final structure message, every
    stage's end-of-stream status and the rig (as vibro graph records them)."""
    from rclpy.serialization import serialize_message

    from vibro_msgs.msg import StreamStatus, StructureMotion
    from vibro_ros import topics
    from vibro_ros.bags import BagWriter

    bag = tmp_path_factory.mktemp("bags") / "run1"
    writer = BagWriter(bag, custom_data={"vibro.rig_yaml": RIG_YAML.read_text()})
    writer.add_topic(topics.FRAMES.name, topics.FRAMES.msg_type)  # declared as vibro graph records it (no image
    # needed here; a replay refuses a bag with no image topic at all before it looks at its --out)
    writer.add_topic(topics.STRUCTURE.name, topics.STRUCTURE.msg_type)
    writer.add_topic(topics.STATUS.name, topics.STATUS.msg_type)
    writer.write(topics.STRUCTURE.name, 1, serialize_message(
        StructureMotion(amplitude_mm=1.5, frequency_hz=22.0, phase_rad=0.1, offset_mm=0.0)))
    for k, stream in enumerate(("flights", "impacts", "simulation", "discrepancy")):
        writer.write(topics.STATUS.name, 2 + k, serialize_message(StreamStatus(stream=stream, finished=True)))
    writer.close()
    return bag


def test_results_refuses_then_overwrites(result_bag, tmp_path, capsys):
    out = tmp_path / "res"
    out.mkdir()
    (out / "results.json").write_text('{"stale": true}')
    before = snapshot(out)
    refused(capsys, ["results", str(result_bag), "--out", str(out)])
    assert snapshot(out) == before
    assert main(["results", str(result_bag), "--out", str(out), "--overwrite"]) == 0
    doc = json.loads((out / "results.json").read_text())
    assert doc["structure"]["amplitude_mm"] == 1.5 and "stale" not in doc
    (out / "keep.txt").write_text("mine")
    before = snapshot(out)
    assert "keep.txt" in refused(capsys, ["results", str(result_bag), "--out", str(out), "--overwrite"])
    assert snapshot(out) == before
    # a .json --out is one file: refused when it exists, replaced with --overwrite
    one = tmp_path / "one.json"
    one.write_text("mine")
    refused(capsys, ["results", str(result_bag), "--out", str(one)])
    assert one.read_text() == "mine"
    assert main(["results", str(result_bag), "--out", str(one), "--overwrite"]) == 0
    assert json.loads(one.read_text())["structure"]["frequency_hz"] == 22.0
    assert not temp_leftovers(tmp_path)


def test_results_beside_its_bag(result_bag, tmp_path):
    # vibro graph rec --bag DIR/bag; vibro results DIR/bag --out DIR: the bag and its logs are inputs, kept
    work = tmp_path / "w"
    shutil.copytree(result_bag, work / "bag")
    (work / "bag.logs").mkdir()
    (work / "bag.logs" / "recorder.log").write_text("log")
    before = snapshot(work)
    assert main(["results", str(work / "bag"), "--out", str(work)]) == 0
    assert json.loads((work / "results.json").read_text())["structure"]["amplitude_mm"] == 1.5
    assert {k: v for k, v in snapshot(work).items() if k != "results.json"} == before


def test_results_and_replay_bad_out_paths(result_bag, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for command in ("results", "replay"):
        for out in ("/proc/x", str(a_file)):
            assert out in refused(capsys, [command, str(result_bag), "--out", out])
    assert a_file.read_text() == "x"


def test_graph_bad_bag_paths(tiny_recording, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    for bag, extra in (("/proc/x", []), (str(a_file), []), (str(a_file), ["--overwrite"])):
        assert bag in refused(capsys, ["graph", str(tiny_recording), "--bag", bag, *extra])
    assert a_file.read_text() == "x"
    assert not Path("/proc/x.logs").exists()


def fake_replay_folder(out: Path, source_bag: Path) -> None:
    """What an earlier replay left: rig.yaml, results.json, a real bag and its logs."""
    from vibro_ros.bags import BagWriter

    out.mkdir()
    (out / "rig.yaml").write_text(RIG_YAML.read_text())
    (out / "results.json").write_text('{"stale": true}')
    BagWriter(out / "bag").close()
    (out / "bag.logs").mkdir()
    (out / "bag.logs" / "dic_tracker.log").write_text("log")


def test_replay_refusals_before_any_node_starts(result_bag, tmp_path, capsys):
    out = tmp_path / "re"
    fake_replay_folder(out, result_bag)
    before = snapshot(out)
    refused(capsys, ["replay", str(result_bag), "--out", str(out)])
    assert snapshot(out) == before
    (out / "bag" / "my_notes.txt").write_text("mine")  # inside the bag: the folder is no longer ours
    before = snapshot(out)
    assert "bag/" in refused(capsys, ["replay", str(result_bag), "--out", str(out), "--overwrite"])
    assert snapshot(out) == before


def test_a_bag_with_no_images_is_refused_before_an_earlier_replay_is_overwritten(tmp_path, capsys):
    # the bag's content is checked before --overwrite clears the output folder: a replay that cannot run must
    # not cost the user the previous replay's outputs
    from vibro_ros import topics
    from vibro_ros.bags import BagWriter

    bag = tmp_path / "no_images"
    writer = BagWriter(bag, custom_data={"vibro.rig_yaml": RIG_YAML.read_text()})
    writer.add_topic(topics.STATUS.name, topics.STATUS.msg_type)
    writer.close()
    out = tmp_path / "re"
    fake_replay_folder(out, bag)
    before = snapshot(out)
    assert "no camera images recorded" in refused(capsys, ["replay", str(bag), "--out", str(out), "--overwrite"])
    assert snapshot(out) == before


def test_replay_and_graph_outputs_are_recognised_as_their_own(result_bag, tmp_path):
    # what --overwrite removes for replay (and graph) matches what BagWriter and the node logs really write
    from vibro_app.cmd_replay import REPLAY_OUTPUTS
    from vibro_bringup.graph_runner import new_bag_path

    out = tmp_path / "re"
    fake_replay_folder(out, result_bag)
    prepare_output_dir(out, overwrite=True, owned=REPLAY_OUTPUTS, command="replay")
    assert list(out.iterdir()) == []
    fake_replay_folder(tmp_path / "g", result_bag)
    with pytest.raises(OutputError, match="already exists"):
        new_bag_path(tmp_path / "g" / "bag")
    assert new_bag_path(tmp_path / "g" / "bag", overwrite=True) == tmp_path / "g" / "bag"
    assert sorted(p.name for p in (tmp_path / "g").iterdir()) == ["results.json", "rig.yaml"]  # not graph's


@pytest.mark.parametrize("command", ["graph", "replay"])
@pytest.mark.parametrize("domain_id", ["999", "-3", "233", "x"])
def test_domain_id_out_of_range_is_an_argparse_error(command, domain_id, tiny_recording, tmp_path, capsys):
    target = ["graph", str(tiny_recording), "--bag", str(tmp_path / "b")] if command == "graph" else \
        ["replay", str(tmp_path / "bag")]
    with pytest.raises(SystemExit) as exc:
        main([*target, "--domain-id", domain_id])
    assert exc.value.code == 2
    assert "--domain-id" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_domain_id_range_ends_are_accepted():
    from vibro_app.cli import build_parser

    parser = build_parser()
    for value in (0, 232):
        assert parser.parse_args(["replay", "bag", "--domain-id", str(value)]).domain_id == value


# --- atomic writes ---------------------------------------------------------------------------------------

def test_a_crash_mid_write_leaves_the_previous_file_and_no_temp(tmp_path):
    target = tmp_path / "results.json"
    target.write_text('{"run": 1}\n')
    new = json.dumps({"run": 2, "impacts": list(range(1000))})
    with pytest.raises(RuntimeError, match="crash"):
        with atomic_open(target) as handle:
            handle.write(new[: len(new) // 2])
            handle.flush()
            assert target.read_text() == '{"run": 1}\n'  # the half is not under the target's name
            raise RuntimeError("crash")
    assert target.read_text() == '{"run": 1}\n'
    assert list(tmp_path.iterdir()) == [target]
    atomic_write_text(target, new)
    assert json.loads(target.read_text())["run"] == 2 and list(tmp_path.iterdir()) == [target]
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask  # the mode a plain write gives


def test_a_killed_writer_leaves_the_previous_file(tmp_path):
    # SIGKILL in the middle of writing: no cleanup can run; the target still holds the earlier run
    target = tmp_path / "results.json"
    target.write_text('{"run": 1}\n')
    code = ("import os, signal, sys\n"
            "from vibro_io.outputs import atomic_open\n"
            "with atomic_open(sys.argv[1]) as h:\n"
            "    h.write('{\"run\": 2, \"half'); h.flush(); os.kill(os.getpid(), signal.SIGKILL)\n")
    res = subprocess.run([sys.executable, "-c", code, str(target)], capture_output=True, text=True, timeout=60)
    assert res.returncode == -signal.SIGKILL
    assert target.read_text() == '{"run": 1}\n'
    left = temp_leftovers(tmp_path)
    assert len(left) == 1 and left[0].name.startswith(".results.json.")  # recognised by --overwrite (fit test)


def test_output_error_is_a_recording_error():
    # the CLI prints RecordingError as one line with exit code 2
    assert issubclass(OutputError, RecordingError)
