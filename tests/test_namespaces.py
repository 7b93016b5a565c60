"""#16.4: vibro graphs under ROS namespaces (-r __ns:=/lab1), as a lab runs several rigs on one domain.

Real node processes; a probe node in the test process looks at them through the ROS graph API, their
parameter services, /diagnostics and their topics.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
from pathlib import Path

from ros_probe import Probe

from vibro_bringup.graph_spec import BAG_SOURCE, NODES, node_parameters, write_params_file
from vibro_ros import topics
from vibro_ros.node_help import node_interface
from vibro_ros.node_support import history_qos


def _node_class(module: str) -> type:
    import importlib

    from rclpy.node import Node

    mod = importlib.import_module(module)
    (cls,) = [c for c in vars(mod).values() if isinstance(c, type) and issubclass(c, Node) and c is not Node
              and c.__module__ == module]
    return cls


def test_every_vibro_topic_is_relative_except_diagnostics() -> None:
    assert [t.name for t in topics.ALL_TOPICS if t.name.startswith("/")] == ["/diagnostics"]
    for spec in (*NODES, BAG_SOURCE):
        interface = node_interface(_node_class(spec.module))
        absolute = {t.name for t in interface.topics if t.name.startswith("/")}
        assert absolute == {"/diagnostics"}, f"{spec.name}: absolute topics {absolute}"
        assert all(not t.name.startswith("<") for t in interface.topics), interface.topics  # all resolved


def _start_node(module: str, namespace: str, params_file: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "vibro_bringup.child", module, "--ros-args",
                             "-r", f"__ns:={namespace}", "--params-file", str(params_file)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _stop(procs: list[subprocess.Popen]) -> dict[int, str]:
    errs = {}
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            errs[p.pid] = p.communicate(timeout=20)[1]
        except subprocess.TimeoutExpired:
            p.kill()
            errs[p.pid] = p.communicate()[1]
    return errs


def test_two_namespaced_graphs_on_one_domain_get_their_params_and_stay_apart(
        tiny_recording: Path, tmp_path: Path, ros_domain: str) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import Image

    from vibro_msgs.msg import DicFrame
    from vibro_ros.node_support import STREAM_QOS

    # /lab1 streams the 5-frame fixture; /lab2 the same rig cut to its first 3 frames
    short = tmp_path / "short"
    shutil.copytree(tiny_recording, short)
    for k in (3, 4):
        (short / "frames" / f"{k:06d}.png").unlink()
    labs = {"/lab1": (tiny_recording, 5, 0.55), "/lab2": (short, 3, 0.65)}
    procs = []
    with Probe() as probe:
        diagnostics = probe.subscribe(DiagnosticArray, "/diagnostics")
        # vibro/dic is a latched history: the probe (in /, so no declared reader of a /labN tracker) gets it all
        dic = {ns: probe.subscribe(DicFrame, f"{ns}/vibro/dic", history_qos(100)) for ns in labs}
        frames = {ns: probe.subscribe(Image, f"{ns}/vibro/frames", STREAM_QOS) for ns in labs}
        for ns, (rec, _, zncc_min) in labs.items():
            # the params file as `vibro graph` writes it, applied to namespaced nodes
            params = node_parameters(rec, None)
            # just the two nodes: each declares the other as its reader (the table's others are not started); the
            # tracker stays up after the stream (exit_when_done false) so that its parameters can be read
            params["dic_tracker"].update(zncc_min=zncc_min, readers=["frame_source"], exit_when_done=False)
            params["frame_source"]["readers"] = ["dic_tracker"]
            # the probe is no declared reader, and discovering a node took it 2-3 s here: the source streams at
            # 1 frame/s (its diagnostics go out every 1 s) so that it is still up when the probe matches it
            params["frame_source"]["rate_hz"] = 1.0
            params_file = write_params_file(params, tmp_path / f"params{ns.replace('/', '_')}.yaml")
            procs.append(_start_node("vibro_dic.dic_tracker_node", ns, params_file))
            procs.append(_start_node("vibro_dic.frame_source_node", ns, params_file))
        try:
            streamed = probe.spin_until(lambda: all(len(dic[ns]) >= n for ns, (_, n, _) in labs.items()), 90)
            # every node reports on the root /diagnostics, named by its full name (a source that ran
            # < 1 s reports once, as it stops)
            expected_names = {f"{ns}/{node}" for ns in labs for node in ("dic_tracker", "frame_source")}
            probe.spin_until(lambda: expected_names <= {s.name for m in diagnostics for s in m.status}, 30)
            probe.spin(1.0)  # anything a leak would add arrives by now
            names = {s.name for msg in diagnostics for s in msg.status}
            got_params = {ns: probe.get_parameters(f"{ns}/dic_tracker", ["zncc_min", "rig_file"]) for ns in labs}
            tracker_topics = probe.topics_of("/lab1/dic_tracker")
            all_topics = {name for name, _ in probe.node.get_topic_names_and_types()}
        finally:
            errs = _stop(procs)
    assert streamed, f"DicFrames received: { {ns: len(v) for ns, v in dic.items()} }\n" + "\n".join(errs.values())
    for ns, (rec, n_frames, zncc_min) in labs.items():
        # each tracker saw only its own source's frames: a leak would add /lab1's frames 3, 4 to /lab2
        assert [m.frame_index for m in dic[ns]] == list(range(n_frames)), ns
        # frames are a volatile stream the source sends once its declared reader (the tracker) has matched: the
        # probe may join late and miss some, never get more (/lab1's 5 frames leaking into /lab2 would)
        assert len(frames[ns]) <= n_frames, ns
        assert not any(m.lost for m in dic[ns]), ns
        # the params file applied under the namespace (a bare `dic_tracker:` key would not)
        assert got_params[ns] == {"zncc_min": zncc_min, "rig_file": str((rec / "rig.yaml").resolve())}
        assert {f"{ns}/dic_tracker", f"{ns}/frame_source"} <= names, names
    assert "/diagnostics" in all_topics and not {"/lab1/diagnostics", "/lab2/diagnostics"} & all_topics
    # the running tracker's topics are its --help listing moved into the namespace
    pubs, subs = tracker_topics
    interface = node_interface(_node_class("vibro_dic.dic_tracker_node"))

    def expected(direction: str) -> set[str]:
        return {t.name if t.name.startswith("/") else f"/lab1/{t.name}" for t in interface.topics
                if t.direction == direction}

    assert pubs == expected("publishes") and subs == expected("subscribes"), (pubs, subs)
    assert all(t.startswith("/lab1/vibro/") or t == "/diagnostics" for t in pubs | subs)
    for err in errs.values():
        assert "Traceback" not in err and "arrived after" not in err, err


def test_the_graph_summary_counts_every_status_stream_on_its_topic() -> None:
    # the stream names are listed twice (node side: vibro_ros.topics, summary side: cmd_graph); a stream added
    # to one and not the other would go unchecked against the bag
    from vibro_bringup.graph_runner import STREAM_TOPICS
    from vibro_ros import topics

    assert set(STREAM_TOPICS) == set(topics.STATUS_STREAMS)
    names = {t.name for t in topics.ALL_TOPICS}
    assert all(topic == f"vibro/{stream}" and topic in names for stream, (topic, _, _) in STREAM_TOPICS.items())
