"""vibro graph's process supervisor (vibro_bringup.supervisor) with tiny dummy child processes."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from vibro_bringup.graph_runner import Linger, _stop_lingering
from vibro_bringup.graph_spec import NodeSpec
from vibro_bringup.supervisor import Supervisor
from vibro_ros.topics import STATUS_STREAMS

#: A dummy node: notes its start, then exits with CODE after DELAY s, or (CODE "run") runs until SIGINT,
#: noting when it got it; "deaf" ignores SIGINT.
CHILD = r'''
import signal, sys, time
from vibro_ros.entry import install_stack_dump
install_stack_dump()  # as every node's process does (vibro_ros.entry.prepare_node_process)
name, code, delay, journal = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
def note(text):
    with open(journal, "a") as f:
        f.write(f"{time.monotonic():.4f} {text} {name}\n")
stop = []
if code in ("run", "deaf"):  # before "start" is noted: the test may send SIGINT as soon as it reads that
    signal.signal(signal.SIGINT, (lambda *a: stop.append(1)) if code == "run" else signal.SIG_IGN)
note("start")
print(f"{name}: working", flush=True)
def wait_for_sigint_deaf_or_not():
    while not stop:
        time.sleep(0.01)
if code in ("run", "deaf"):
    wait_for_sigint_deaf_or_not()
    note("stop")
    sys.exit(0)
time.sleep(delay)
print(f"{name}: boom, giving up with {code}", flush=True)
sys.exit(int(code))
'''


#: what the dummy nodes named here publish (the others: nothing): the streams whose end they announce
PUBLISHES = {"fitter": ("vibro/flights", "vibro/impacts")}


def _spec(name: str, role: str) -> NodeSpec:
    return NodeSpec(name=name, package="pkg", executable=name, module=f"pkg.{name}", role=role,
                    publishes=PUBLISHES.get(name, ()))


@pytest.fixture
def make(tmp_path: Path):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    journal = tmp_path / "journal.txt"

    def build(behaviour: dict[str, tuple[str, str, float]], respawn: int = 2) -> Supervisor:
        specs = [_spec(name, role) for name, (role, _, _) in behaviour.items()]

        def command(spec: NodeSpec) -> list[str]:
            build.started.append(spec.name)  # the order in which the supervisor starts processes
            _, code, delay = behaviour[spec.name]
            return [sys.executable, str(script), spec.name, code, str(delay), str(journal)]

        sup = Supervisor(specs, command, tmp_path, respawn=respawn, announce=build.said.append)
        build.made.append(sup)
        return sup

    build.journal = journal
    build.started = []
    build.said = []
    build.made = []
    yield build
    for sup in build.made:  # a test that failed midway leaves no child running (a "deaf" one ignores SIGINT)
        for proc in sup.procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def _journal(path: Path) -> list[tuple[float, str, str]]:
    return [(float(t), what, name) for t, what, name in (line.split() for line in path.read_text().splitlines())]


def _run_until(sup: Supervisor, until, timeout_s: float = 20.0) -> list:
    failures = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not until(failures):
        failures += sup.poll()
        time.sleep(0.02)
    return failures


def test_starts_sink_then_processing_then_sources_and_sees_them_finish(make) -> None:
    sup = make({"src": ("source", "0", 0.1), "proc_a": ("processing", "0", 0.3), "rec": ("sink", "0", 0.5),
                "proc_b": ("processing", "0", 0.2)})
    sup.start_all()
    failures = _run_until(sup, lambda f: f or sup.all_finished())
    assert not failures and sup.all_finished() and sup.finished == {"src", "proc_a", "proc_b", "rec"}
    assert make.started == ["rec", "proc_a", "proc_b", "src"]  # sink, processing (table order), sources
    assert sorted(n for _, what, n in _journal(make.journal) if what == "start") == sorted(make.started)
    assert not sup.restarts


def test_a_processing_node_is_restarted_then_given_up_with_its_log(make, tmp_path: Path) -> None:
    # a crash: exit code 5 (2 is a refusal and 3 an incomplete run, vibro_ros.exit_codes: never restarted)
    sup = make({"proc": ("processing", "5", 0.05), "rec": ("sink", "run", 0)}, respawn=2)
    sup.start_all()
    failures = _run_until(sup, lambda f: f)
    assert [f.name for f in failures] == ["proc"] and failures[0].code == 5 and failures[0].restarts == 2
    assert sup.restarts == {"proc": 2}
    assert sum(1 for _, what, n in _journal(make.journal) if what == "start" and n == "proc") == 3
    log = (tmp_path / "proc.log").read_text()
    assert log.count("restarted (") == 2 and "restarted (2/2)" in log
    assert "proc: boom, giving up with 5" in failures[0].describe()
    assert not sup.all_finished()
    sup.stop(grace_s=5)


def test_a_dead_source_fails_at_once_and_is_not_restarted(make) -> None:
    sup = make({"src": ("source", "2", 0.05), "proc": ("processing", "run", 0), "rec": ("sink", "run", 0)})
    t0 = time.monotonic()
    sup.start_all()
    failures = _run_until(sup, lambda f: f)
    assert time.monotonic() - t0 < 5.0
    assert [(f.name, f.code, f.restarts) for f in failures] == [("src", 2, 0)] and not sup.restarts
    assert "src: boom, giving up with 2" in failures[0].tail
    # a dead recorder is a failure too (never restarted: it cannot resume the bag)
    sup.procs["rec"].kill()
    later = _run_until(sup, lambda f: f)
    assert [(f.name, f.code) for f in later] == [("rec", -9)]
    sup.stop(grace_s=5)


def test_stops_sources_then_processing_then_drains_before_the_sink(make) -> None:
    sup = make({"rec": ("sink", "run", 0), "proc": ("processing", "run", 0), "src": ("source", "run", 0),
                "deaf": ("processing", "deaf", 0)})
    sup.start_all()
    deadline = time.monotonic() + 10
    while len([1 for _, what, _ in _journal(make.journal) if what == "start"]) < 4 if make.journal.exists() else True:
        assert time.monotonic() < deadline
        time.sleep(0.02)
    killed = sup.stop(grace_s=2.0, drain_s=0.4)
    assert killed == ["deaf"]  # ignores SIGINT: killed once the grace time is over
    # and says where it was: its threads' stacks (SIGUSR1 before the kill) come with the end of its log
    [said] = [text for text in make.said if "deaf did not stop" in text]
    assert "wait_for_sigint_deaf_or_not" in said and "most recent call first" in said
    stops = {name: t for t, what, name in _journal(make.journal) if what == "stop"}
    assert set(stops) == {"rec", "proc", "src"}
    assert stops["src"] < stops["proc"] < stops["rec"]
    assert stops["rec"] - stops["proc"] >= 0.4  # the drain before the recorder
    assert all(p.poll() is not None for p in sup.procs.values())


def _wait_for_starts(journal: Path, n: int, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not journal.exists() or sum(1 for _, what, _ in _journal(journal) if what == "start") < n:
        assert time.monotonic() < deadline, "the dummy nodes did not start"
        time.sleep(0.02)


def test_a_node_up_after_its_streams_ended_and_the_rest_finished_is_lingering(make) -> None:
    sup = make({"rec": ("sink", "0", 0.3), "fitter": ("processing", "deaf", 0), "sim": ("processing", "0", 0.2),
                "src": ("source", "0", 0.1)})
    sup.start_all()
    _wait_for_starts(make.journal, 4)
    ended = {"flights", "impacts"}  # the fitter's two streams, as the monitor saw them end
    assert sup.lingering(ended) == []  # the others are still working: nothing is over yet
    _run_until(sup, lambda f: f or sup.finished == {"rec", "sim", "src"})
    assert sup.finished == {"rec", "sim", "src"}
    assert sup.lingering(ended) == ["fitter"]
    assert sup.lingering({"impacts"}) == []  # one of its streams has not ended: it may still be working
    assert sup.lingering(set()) == []
    sup.stop(grace_s=1.0)


def test_a_node_without_streams_never_lingers(make) -> None:
    # the recorder announces no stream: up while the others have finished, it is closing the bag, not hung
    sup = make({"rec": ("sink", "run", 0), "src": ("source", "0", 0.05)})
    sup.start_all()
    _run_until(sup, lambda f: f or sup.finished == {"src"})
    assert sup.lingering(set(STATUS_STREAMS)) == []
    sup.stop(grace_s=2.0)


def test_linger_clock_restarts_when_the_lingering_nodes_change() -> None:
    linger = Linger(limit_s=0.2)
    assert not linger.over(["fitter"])
    time.sleep(0.25)
    assert linger.over(["fitter"])
    assert not linger.over(["fitter", "simulator"])  # another node joined: a new clock
    assert not linger.over([])
    time.sleep(0.25)
    assert not linger.over([])  # nothing lingering is never over


def test_a_lingering_node_is_stopped_with_its_stacks_and_a_warning(make, capsys) -> None:
    sup = make({"fitter": ("processing", "deaf", 0), "src": ("source", "0", 0.05)})
    sup.start_all()
    _run_until(sup, lambda f: f or sup.finished == {"src"})
    linger = Linger(limit_s=0.0)
    assert linger.over(["fitter"])
    _stop_lingering(sup, linger, grace_s=1.0)
    assert sup.procs["fitter"].poll() is not None  # deaf to SIGINT: killed
    err = capsys.readouterr().err
    assert "warning: fitter is still running" in err and "stopping it" in err
    assert "wait_for_sigint_deaf_or_not" in (sup.logs["fitter"]).read_text()  # the stacks, dumped before the stop
