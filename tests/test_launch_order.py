"""The launch file's node set (graph_spec.launch_nodes) started the way ros2 launch starts it -- separate
processes, console-script mains, the function's own parameters and remappings -- in shuffled order with
random delays, gives what `vibro graph` gives on the same recording, and every node exits by itself."""

from __future__ import annotations

import os
import random
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from domains import private_domain

sys.path.insert(0, str(Path(__file__).resolve().parent))
from launch_like import console_scripts, run_as_launch  # noqa: E402

VIBRO = [sys.executable, "-m", "vibro_app.cli"]


@pytest.fixture(scope="module")
def recording(reference_run: dict) -> Path:
    """The shared run's recording: 300 frames with asymmetric restitution, so that the discrepancy analysis
    has a finding to compare."""
    return reference_run["rec"]


def test_every_launch_node_is_a_console_script_of_its_package(recording: Path, tmp_path: Path) -> None:
    from vibro_bringup.graph_spec import LiveDaq, launch_nodes

    scripts = console_scripts()
    nodes = launch_nodes(recording, tmp_path / "bag", reference_dir=tmp_path)
    assert {n.spec.name for n in nodes} == {"recorder", "dic_tracker", "impact_detector", "trajectory_fitter",
                                           "simulator", "discrepancy", "frame_source", "accel_source"}
    from vibro_ros.entry import NODE_MODULES

    for n in nodes:  # through the light entry module (early Ctrl-C), which runs the table's node module
        assert scripts[(n.spec.package, n.spec.executable)] == f"vibro_ros.entry:{n.spec.executable}", n.spec
        assert NODE_MODULES[n.spec.executable] == n.spec.module, n.spec
    # live: no file source, the camera topic remapped, processing nodes stay up and respawn; no end-of-run
    # nodes (simulator, discrepancy: a live stream never ends, they would only hoard DicFrames); camera-only,
    # though this recording has accelerometer files (an old run's, which would mix its impacts into this one)
    live = {n.spec.name: n for n in launch_nodes(recording, None, live=True, camera_topic="/camera/image_raw")}
    assert set(live) == {"dic_tracker", "trajectory_fitter"}
    assert live["trajectory_fitter"].parameters["use_accelerometers"] is False
    assert live["dic_tracker"].remappings == (("vibro/frames", "/camera/image_raw"),)
    assert live["dic_tracker"].respawn and live["dic_tracker"].parameters["exit_when_done"] is False
    assert live["dic_tracker"].parameters["readers"] == ["trajectory_fitter"]
    assert live["dic_tracker"].parameters["keep_history_until"] == ["impacts"]
    recorded = {n.spec.name for n in launch_nodes(recording, tmp_path / "live_bag", live=True)}
    assert recorded == set(live) | {"recorder"}
    # live accelerometers from a DAQ driver: the detector joins, no file source, both readers check the blocks
    daq = {n.spec.name: n for n in launch_nodes(recording, None, live=True, camera_topic="/camera/image_raw",
                                                daq=LiveDaq(topic="/daq/accel", rate_hz=50_000.0))}
    assert set(daq) == {"dic_tracker", "trajectory_fitter", "impact_detector"}
    for name in ("trajectory_fitter", "impact_detector"):
        assert daq[name].parameters["live_accel"] is True and daq[name].parameters["accel_rate_hz"] == 50_000.0
        assert ("vibro/accel", "/daq/accel") in daq[name].remappings
    # live, the buffered readers give way to the tracker (its best-effort images are the only ones lost by waiting);
    # from a recording every node keeps its priority
    assert {name: n.parameters.get("cpu_nice", 0) for name, n in daq.items()} == {
        "dic_tracker": 0, "trajectory_fitter": 5, "impact_detector": 5}
    assert all("cpu_nice" not in n.parameters for n in nodes)
    assert daq["trajectory_fitter"].parameters["use_accelerometers"] is True


def test_reader_topics_pair_every_declared_reader_with_topics_the_node_publishes(recording: Path, tmp_path: Path
                                                                                 ) -> None:
    import yaml

    from vibro_bringup.graph_spec import ALL_SPECS, RunSetup, default_params_file, launch_nodes

    for node in launch_nodes(recording, tmp_path / "bag", reference_dir=tmp_path):
        if node.spec.role == "sink":
            assert "reader_topics" not in node.parameters
            continue
        pairs = [tuple(p.split("=")) for p in node.parameters["reader_topics"] if p]
        published = set(node.spec.publishes) | {"vibro/status"}
        assert {r for r, _ in pairs} == set(node.parameters["readers"]) - {""}, node.spec.name
        assert all(t in published and t in ALL_SPECS[r].subscribes for r, t in pairs), (node.spec.name, pairs)
    simulator = next(n for n in launch_nodes(recording, tmp_path / "bag", reference_dir=tmp_path)
                     if n.spec.name == "simulator")
    assert "recorder=vibro/simulation" in simulator.parameters["reader_topics"]  # not only its vibro/status
    # a recorder told not to record the frames is not waited for on them (it never subscribes)
    base = yaml.safe_load(default_params_file().read_text())
    key = next(k for k in base if k.endswith("recorder"))
    base[key]["ros__parameters"]["exclude_topics"] = ["vibro/frames"]
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(base))
    source = next(n for n in launch_nodes(recording, tmp_path / "bag", reference_dir=tmp_path,
                                          setup=RunSetup(base=tmp_path / "p.yaml")) if n.spec.name == "frame_source")
    assert "recorder=vibro/status" in source.parameters["reader_topics"]
    assert "recorder=vibro/frames" not in source.parameters["reader_topics"]


def test_the_monitor_subscribes_to_what_the_node_table_says(recording: Path, ros_domain: str) -> None:
    """MONITOR_SUBSCRIBES (the monitor's reader_topics pairs) is the vibro graph monitor's own subscriptions: a topic
    listed but not subscribed would hold every writer until wait_for_readers_s; one subscribed but not listed
    would be the any-topic race again."""
    from vibro_bringup.graph_runner import GraphSummary, Monitor
    from vibro_bringup.graph_spec import MONITOR_SUBSCRIBES
    from vibro_bringup.isolation import new_run_identity

    identity = new_run_identity()
    monitor = Monitor(GraphSummary(), recording, identity)
    try:
        subscribed = {s.topic_name for s in monitor.node.subscriptions} - {"/parameter_events"}
    finally:
        monitor.close()
    assert subscribed == {f"{identity.namespace}/{t}" for t in MONITOR_SUBSCRIBES}


def test_launch_in_any_order_equals_vibro_graph(recording: Path, reference_run: dict, tmp_path: Path) -> None:
    from vibro_app.bag_results import results_from_bag
    from vibro_bringup.graph_spec import launch_nodes
    from vibro_ros.bags import deserialize, make_typestore, read_messages

    # 1. vibro graph (the supervisor's order: recorder, processing, sources): the shared run of this recording
    graph_stdout = reference_run["graph_stdout"]
    assert "frames in 300 / tracked 300 / lost 0" in graph_stdout, graph_stdout
    domain = private_domain()

    # 2. the launch file's nodes, shuffled, each waiting for its declared readers, exiting by itself
    nodes = launch_nodes(recording, tmp_path / "launch_bag", reference_dir=tmp_path)
    seed = random.randrange(10 ** 6)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    logs = tmp_path / "logs"
    logs.mkdir()
    t0 = time.monotonic()
    codes = run_as_launch(nodes, logs, env, seed)
    elapsed = time.monotonic() - t0
    texts = {p.stem: p.read_text() for p in logs.glob("*.log")}
    assert codes == {n.spec.name: 0 for n in nodes}, (seed, codes, {k: v[-1500:] for k, v in texts.items()})
    assert not [k for k, v in texts.items() if "Traceback" in v], seed

    # 3. the same results: the same CDR-identical frames through the same deterministic code
    a, b = results_from_bag(reference_run["bag"]), results_from_bag(tmp_path / "launch_bag")
    assert len(a["impacts"]) == len(b["impacts"]) >= 8
    for x, y in zip(a["impacts"], b["impacts"]):
        assert x["plate"] == y["plate"] and abs(x["cor"] - y["cor"]) < 1e-6 and abs(x["t"] - y["t"]) < 1e-9
    for model in ("cor_model", "hertz_model"):
        assert abs(a["simulation"][model]["deviation"] - b["simulation"][model]["deviation"]) < 1e-6
    fa, fb = a["discrepancy"]["findings"], b["discrepancy"]["findings"]
    assert [f["effect"] for f in fa] == [f["effect"] for f in fb] == ["asymmetric_restitution"], (fa, fb)
    for x, y in zip(fa, fb):
        assert x["parameters"].keys() == y["parameters"].keys()
        assert all(abs(x["parameters"][k] - y["parameters"][k]) < 1e-6 for k in x["parameters"])
        assert abs(x["deviation_after"] - y["deviation_after"]) < 1e-6

    # 4. every frame accounted for in the launched graph's bag: 300 images, one tracked DicFrame each
    store = make_typestore()
    frames = sum(1 for _ in read_messages(tmp_path / "launch_bag", {"vibro/frames"}))
    dic = {m.frame_index: m for m in (deserialize(x, store)
                                      for x in read_messages(tmp_path / "launch_bag", {"vibro/dic"}))}
    assert frames == 300 and sorted(dic) == list(range(300)) and not any(m.lost for m in dic.values())
    print(f"launch order seed {seed}: all {len(nodes)} nodes exited 0 in {elapsed:.1f} s; "
          f"max |dCOR| {max(abs(x['cor'] - y['cor']) for x, y in zip(a['impacts'], b['impacts'])):.2e}, "
          f"D cor_model {a['simulation']['cor_model']['deviation']:.6g} vs "
          f"{b['simulation']['cor_model']['deviation']:.6g}, "
          f"D hertz_model {a['simulation']['hertz_model']['deviation']:.6g} vs "
          f"{b['simulation']['hertz_model']['deviation']:.6g}, finding cor_top "
          f"{fa[0]['parameters']['cor_top']:.6g} vs {fb[0]['parameters']['cor_top']:.6g}")


def _main_of(module: str) -> list[str]:
    """A node started as its console script does it (``sys.exit(main())``)."""
    return [sys.executable, "-c", f"import sys; from {module} import main; sys.exit(main())"]


def test_ctrl_c_to_the_process_group_and_launchs_own_sigint_exit_0(tiny_recording: Path, ros_domain: str) -> None:
    """ros2 launch: Ctrl-C reaches every process of the group, then launch sends SIGINT itself. rclpy's own
    signal handlers leave SIGINT at its default action after the first one, so the second killed the node
    (launch: "process has died ... exit code -2"); the nodes must stop with 0 and no traceback."""
    import signal

    proc = subprocess.Popen([*_main_of("vibro_dic.frame_source_node"), "--ros-args", "-p",
                             f"recording:={tiny_recording}", "-p", "readers:=[nobody]"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        line = ""
        while "frames from" not in line:  # the node is up (rclpy initialised), waiting for its reader
            line = proc.stdout.readline()
            assert line or proc.poll() is None, "frame_source exited early"
        time.sleep(0.5)
        os.killpg(proc.pid, signal.SIGINT)
        time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0 and "Traceback" not in out, (proc.returncode, out)


def test_readers_are_matched_by_name_in_the_nodes_namespace_or_the_node_fails(tiny_recording: Path,
                                                                              ros_domain: str) -> None:
    """A dic_tracker in another namespace is not this frame_source's declared reader: after
    wait_for_readers_s the source fails (exit 1) naming the missing reader, and has sent nothing."""
    tracker = subprocess.Popen([*_main_of("vibro_dic.dic_tracker_node"), "--ros-args", "-r", "__ns:=/elsewhere",
                                "-p", f"rig_file:={tiny_recording / 'rig.yaml'}"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        res = subprocess.run([*_main_of("vibro_dic.frame_source_node"), "--ros-args", "-r", "__ns:=/here",
                              "-p", f"recording:={tiny_recording}", "-p", "readers:=[dic_tracker]",
                              "-p", "wait_for_readers_s:=4.0"], capture_output=True, text=True, timeout=60)
    finally:
        tracker.terminate()
        tracker.wait(timeout=30)
    assert res.returncode == 1, res.stdout + res.stderr
    assert re.search(r"declared readers dic_tracker never matched [^;]*/here/vibro/frames", res.stderr), res.stderr
    assert "waiting for readers dic_tracker" in res.stderr  # said while waiting, before failing
    assert "streaming:" not in res.stderr and "Traceback" not in res.stderr


_LATE_READER = r'''
import sys, time
import rclpy
from sensor_msgs.msg import Image
from vibro_msgs.msg import StreamStatus
from vibro_ros.node_support import RESULTS_QOS, STREAM_QOS
rclpy.init()
node = rclpy.create_node("probe", namespace="/here")
node.create_subscription(StreamStatus, "vibro/status", lambda m: None, RESULTS_QOS)
got = []
start = time.monotonic()
while time.monotonic() - start < float(sys.argv[1]):  # seen on vibro/status only, for a while
    rclpy.spin_once(node, timeout_sec=0.05)
node.create_subscription(Image, "vibro/frames", got.append, STREAM_QOS)
print("subscribed to frames", flush=True)
while len(got) < int(sys.argv[2]) and time.monotonic() - start < 60:
    rclpy.spin_once(node, timeout_sec=0.05)
print(f"frames received {len(got)}", flush=True)
'''


def test_a_reader_counts_only_once_matched_on_each_of_its_topics(tiny_recording: Path, ros_domain: str) -> None:
    """Each subscription of a node is discovered on its own: a reader seen on vibro/status is not yet a reader of
    vibro/frames. With reader_topics (the node table's pairs) the source streams only once its reader is matched
    on the frames too; counted as present on any topic, it sent all 5 frames before the reader's frames
    subscription existed, and they were lost (volatile stream) -- the CI run that recorded 0 of 2 vibro/simulation."""
    from vibro_io.recording import open_recording

    frames = len(open_recording(tiny_recording).frames)
    probe = subprocess.Popen([sys.executable, "-c", _LATE_READER, "3.0", str(frames)], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True)
    try:
        res = subprocess.run([*_main_of("vibro_dic.frame_source_node"), "--ros-args", "-r", "__ns:=/here",
                              "-p", f"recording:={tiny_recording}", "-p", "readers:=[probe]",
                              "-p", "reader_topics:=[probe=vibro/frames, probe=vibro/status]",
                              "-p", "wait_for_readers_s:=30.0"], capture_output=True, text=True, timeout=90)
        out, _ = probe.communicate(timeout=90)
    finally:
        if probe.poll() is None:
            probe.kill()
    assert res.returncode == 0, res.stdout + res.stderr
    assert "subscribed to frames" in out and f"frames received {frames}" in out, out + res.stderr


def test_reader_topics_must_name_a_topic_the_node_publishes(tiny_recording: Path, ros_domain: str) -> None:
    res = subprocess.run([*_main_of("vibro_dic.frame_source_node"), "--ros-args",
                          "-p", f"recording:={tiny_recording}", "-p", "readers:=[dic_tracker]",
                          "-p", "reader_topics:=[dic_tracker=vibro/frame]"], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stdout + res.stderr
    assert "reader_topics" in res.stderr and "/vibro/frame " in res.stderr, res.stderr


@pytest.mark.parametrize("nice, expect", [(3, "raised by 3"), (25, "must be 0 to 19, got 25")])
def test_cpu_nice_lowers_the_nodes_own_priority_or_is_refused(nice: int, expect: str, ros_domain: str) -> None:
    code = ("import os, rclpy\n"
            "from vibro_model.errors import RecordingError\n"
            "from vibro_ros.node_support import cpu_nice_parameter\n"
            "rclpy.init()\n"
            "from rclpy.parameter import Parameter\n"
            f"node = rclpy.create_node('n', parameter_overrides=[Parameter('cpu_nice', value={nice})])\n"
            "before = os.nice(0)\n"
            "try:\n"
            "    cpu_nice_parameter(node)\n"
            "    print('raised by', os.nice(0) - before)\n"
            "except RecordingError as exc:\n"
            "    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert expect in out.stdout
