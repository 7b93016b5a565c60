"""Shared test fixtures and paths."""

from __future__ import annotations

import os
import sys
from pathlib import Path

#: One BLAS / OpenMP / OpenCV thread in every test process and every process a test starts (they inherit the
#: environment): the suite already runs whole test files in parallel (pytest-xdist, three workers on two cores),
#: and each vibro process of a graph run is one more. OpenBLAS' second thread spins while it waits for work: on
#: the suite's small matrices (a 3000 x 11 least squares) it multiplied the CPU time of a call by ~5, and of a
#: whole `vibro analyze` by 1.15 (plain take) to 1.5 (drive change + drag), same results.json. bench/*.py set the
#: same. A value set by the caller wins.
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "OPENCV_FOR_THREADS_NUM": "1"}
for _name, _value in ONE_THREAD.items():
    os.environ.setdefault(_name, _value)
if "numpy" in sys.modules or "cv2" in sys.modules:  # loaded before this file (a plugin): limit it in place
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(int(os.environ["OPENBLAS_NUM_THREADS"]))
    except ImportError:
        pass
    if "cv2" in sys.modules:
        sys.modules["cv2"].setNumThreads(int(os.environ["OPENCV_FOR_THREADS_NUM"]))

import pytest  # noqa: E402
from domains import private_domain  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "tests" / "fixtures"
SHARED = REPO.parent / "shared"


#: CPU seconds each test file took in a measured ``make test`` (tests/file_costs.json, written by
#: bench/suite_cpu.py --costs): the files run heaviest first, so that the pytest-xdist workers (``--dist loadfile``,
#: with xdist's own reorder by test count switched off in the Makefile: it put the few-test heavy files last) do
#: not end with one of them alone: list scheduling. By CPU, not wall time: the two cores are what the suite is
#: short of, and files that mostly wait (a recorder's timeouts, a node killed and restarted) ordered by their wall
#: time all started together and left the cores a quarter idle for the first 80 s. A file not in the table counts
#: as quick.
FILE_COSTS = REPO / "tests" / "file_costs.json"


def file_costs() -> dict[str, float]:
    """{test file name: CPU seconds} from FILE_COSTS; {} when it is missing or unreadable (the order is then
    pytest's: only the suite's length depends on it)."""
    import json

    try:
        table = json.loads(FILE_COSTS.read_text(encoding="utf-8"))
        return {str(k): float(v) for k, v in table["cpu_s"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def pytest_sessionstart(session) -> None:
    """Remove Fast DDS shared-memory ports and segments left by killed processes (earlier runs, and this suite's
    own SIGKILL tests): Fast DDS 2.14 has been seen to lose samples between live participants when stale ones
    are around (eProsima/Fast-DDS#5053, #5469). Once, in the controlling process; a no-op when nothing is
    stale."""
    if hasattr(session.config, "workerinput"):
        return
    import shutil
    import subprocess
    import sys

    tool = shutil.which("fastdds") or str(Path(sys.executable).parent / "fastdds")
    if Path(tool).exists():
        subprocess.run([tool, "shm", "clean"], capture_output=True, timeout=60, check=False)


def pytest_collection_modifyitems(session, config, items) -> None:
    costs = file_costs()
    items.sort(key=lambda item: -costs.get(item.path.name, 0.0))  # stable: file order kept otherwise


def _cpu_s() -> float:
    """CPU seconds (user + system) of this process and of every child it has waited for."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With VIBRO_TEST_CPU_LOG=file: one JSON line per test with its CPU seconds, setup to teardown, its own and
    its waited-for processes' (a graph's nodes included): what bench/suite_cpu.py sums per file. Wall time says
    little on two shared cores; CPU is what the suite's length is made of."""
    log = os.environ.get("VIBRO_TEST_CPU_LOG")
    if not log:
        yield
        return
    import json
    import time

    cpu0, wall0 = _cpu_s(), time.monotonic()
    yield
    row = {"test": item.nodeid, "cpu_s": round(_cpu_s() - cpu0, 3), "wall_s": round(time.monotonic() - wall0, 3),
           "end_unix_s": round(time.time(), 3), "worker": os.environ.get("PYTEST_XDIST_WORKER", "")}
    with open(log, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(row) + "\n")


@pytest.fixture
def tiny_recording() -> Path:
    """The committed 5-frame recording (see fixtures/make_tiny_recording.py)."""
    return FIXTURES / "tiny_recording"


@pytest.fixture
def close_rclpy():
    """rclpy nodes a test made in its own process (append them): destroyed, and rclpy shut down, after it."""
    import rclpy

    nodes = []
    yield nodes
    for n in nodes:
        n.destroy_node()
    if rclpy.ok():
        rclpy.shutdown()


@pytest.fixture
def ros_domain(monkeypatch: pytest.MonkeyPatch) -> str:
    """A private ROS_DOMAIN_ID so parallel test runs on this machine do not cross-talk."""
    domain = private_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", domain)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return domain


@pytest.fixture(scope="session")
def reference_run(tmp_path_factory) -> dict:
    """One clean ``vibro graph`` run shared by every test that only reads its outputs (a graph run costs
    ~30 s; the suite must stay under 8 minutes): 300 synthetic frames with asymmetric restitution (so the
    discrepancy analysis has a finding), its bag, ``vibro analyze`` of the recording and ``vibro results``
    of the bag. Made once per test run, also under pytest-xdist (the first worker makes it under a file
    lock, the others read it). Tests copy what they change; nothing here may be modified.

    Keys: rec, bag, tmp, env (the run's ROS environment), graph_stdout, wall_ns (time before, after the
    run), analyze, bag_doc (the two results.json documents), truth (the synthetic truth).
    """
    import fcntl
    import json

    shared = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        shared = shared.parent  # the base temp directory all workers of this run share
    tmp = shared / "reference_run"
    with open(shared / "reference_run.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (tmp / "run.json").is_file():
            _make_reference_run(tmp)
    run = json.loads((tmp / "run.json").read_text())
    return {"rec": tmp / "rec", "bag": tmp / "bag", "tmp": tmp, "env": dict(os.environ, **run["env"]),
            "graph_stdout": run["graph_stdout"], "wall_ns": tuple(run["wall_ns"]),
            "analyze": json.loads((tmp / "an" / "results.json").read_text()),
            "bag_doc": json.loads((tmp / "bagres" / "results.json").read_text()),
            "truth": json.loads((tmp / "rec.truth.json").read_text())}


def _make_reference_run(tmp: Path) -> None:
    import json
    import subprocess
    import sys
    import time

    from vibro_sim.synth import SynthConfig, synthesize

    if tmp.exists():  # a run that failed half-way: kept beside (its logs say why), not reused
        tmp.rename(tmp.with_name(f"{tmp.name}.failed-{time.time_ns()}"))
    tmp.mkdir(parents=True)
    rec = tmp / "rec"
    synthesize(rec, SynthConfig(frames=300, seed=11, effects={"asymmetric_restitution": {}}), progress=False)
    ros_env = {"ROS_DOMAIN_ID": private_domain(), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    env = dict(os.environ, **ros_env)
    vibro = [sys.executable, "-m", "vibro_app.cli"]

    def run(*args: str) -> subprocess.CompletedProcess:
        res = subprocess.run([*vibro, *args], capture_output=True, text=True, timeout=300, env=env)
        assert res.returncode == 0, f"vibro {' '.join(args)}: exit {res.returncode}\n{res.stdout}\n{res.stderr}"
        return res

    before_ns = time.time_ns()
    graph = run("graph", str(rec), "--bag", str(tmp / "bag"), "--timeout-s", "150")
    after_ns = time.time_ns()
    run("analyze", str(rec), "--out", str(tmp / "an"), "--no-progress", "--no-report")
    run("results", str(tmp / "bag"), "--out", str(tmp / "bagres"))
    (tmp / "run.json").write_text(json.dumps({"env": ros_env, "graph_stdout": graph.stdout,
                                              "wall_ns": [before_ns, after_ns]}))
