"""How a node's own process ends (vibro_ros.entry.exit_now, vibro_ros.node_support.keep_node_objects_until_exit)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import time

#: Fast DDS's default participant lease (s): a participant that vanishes without saying so is dropped by its
#: peers only this long after its last announcement
FASTDDS_LEASE_S = 20.0

SCRIPT = textwrap.dedent("""
    import gc, sys, weakref
    import rclpy.executors
    from rclpy.node import Node
    from rclpy.task import Future
    from vibro_ros import node_support

    class Done(Node):
        def __init__(self):
            super().__init__("vibro_test_exit")
            self.done = Future()
            self.create_timer(0.05, lambda: self.done.set_result(True))

    if sys.argv[1] == "keep":
        node_support.keep_node_objects_until_exit()
    seen = []
    orig = node_support.make_executor
    def spy(kind):
        ex = orig(kind)
        seen.append(weakref.ref(ex))
        return ex
    node_support.make_executor = spy
    code = node_support.run_node(Done, ["x"])
    gc.collect()
    kept = node_support._RETAINED_AT_EXIT or []
    print(code, sum(1 for x in kept if isinstance(x, Node)), seen[0]() is not None)
""")


def _run(mode: str, ros_domain: str) -> list[str]:
    res = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "left the ROS graph with exit code 0" in res.stderr
    return res.stdout.split()


def test_a_node_process_keeps_its_node_and_executor_until_os_exit(ros_domain: str) -> None:
    # in a node's own process the executor and node are never freed after run_node: their destructors would run
    # on a shut-down context, which is where a simulator once hung after leaving the graph
    assert _run("keep", ros_domain) == ["0", "1", "True"]


def test_a_process_that_goes_on_frees_them(ros_domain: str) -> None:
    # a test calling a node's main() in its own process: nothing retained, the executor freed as before
    assert _run("free", ros_domain) == ["0", "0", "False"]


READER = textwrap.dedent("""
    from rclpy.node import Node
    from rclpy.task import Future
    from std_msgs.msg import String
    from vibro_ros import entry, node_support

    class Reader(Node):
        def __init__(self):
            super().__init__("vibro_test_exit_reader")
            self.done = Future()
            self.create_subscription(String, "vibro_test_exit", lambda m: self.done.set_result(True), 10)

    node_support.keep_node_objects_until_exit()   # as a node's entry point
    entry.exit_now(node_support.run_node(Reader, ["x"]))
""")


def test_a_node_that_exits_leaves_its_peers_graph_at_once(ros_domain: str) -> None:
    """A reliable writer must stop counting the reader of a node that exited without waiting for its DDS lease:
    every vibro node waits for its readers' acknowledgements before it exits, so a reader whose participant
    outlives it (the node kept in an executor that still held it) held each of its writers up to 20 s, and a
    300-frame vibro graph run took 47 s instead of 8."""
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    context = Context()
    rclpy.init(context=context)
    try:
        peer = rclpy.create_node("vibro_test_exit_writer", context=context)
        pub = peer.create_publisher(String, "vibro_test_exit",
                                    QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        reader = subprocess.Popen([sys.executable, "-c", READER], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True)
        try:
            deadline = time.monotonic() + 60
            while pub.get_subscription_count() < 1:
                assert time.monotonic() < deadline and reader.poll() is None, reader.communicate()
                time.sleep(0.05)
            pub.publish(String(data="end"))
            _, err = reader.communicate(timeout=60)
        finally:
            if reader.poll() is None:
                reader.kill()
                reader.communicate()
        assert reader.returncode == 0 and "left the ROS graph with exit code 0" in err, err
        exited = time.monotonic()
        while pub.get_subscription_count() > 0 and time.monotonic() - exited < FASTDDS_LEASE_S / 2:
            time.sleep(0.05)
        assert pub.get_subscription_count() == 0, \
            f"the exited reader is still matched {time.monotonic() - exited:.1f} s later: its participant lingers"
        peer.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_running_node_writes_its_threads_stacks_on_sigusr1_and_goes_on(ros_domain: str, tiny_recording,
                                                                         tmp_path) -> None:
    """`kill -USR1` on a node (started as `ros2 run` starts it) writes where each of its threads is to its stderr,
    the main thread in the spin loop, and the node goes on until SIGINT ends it with exit code 0: what vibro graph
    asks of a node before it kills one that hangs (vibro_bringup.supervisor.Supervisor.dump_stacks)."""
    import os
    import signal

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from launch_like import console_scripts
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    module, func = console_scripts()[("vibro_sim", "simulator")].split(":")
    log = tmp_path / "simulator.log"
    context = Context()
    rclpy.init(context=context)
    with log.open("w") as out:
        proc = subprocess.Popen([sys.executable, "-c", f"import sys; from {module} import {func}; sys.exit({func}())",
                                 "--ros-args", "-r", "__node:=simulator", "-r", "__ns:=/vibro_test_stacks",
                                 "-p", f"rig_file:={tiny_recording / 'rig.yaml'}"],
                                stdout=out, stderr=subprocess.STDOUT, env=dict(os.environ))
    try:
        peer = rclpy.create_node("vibro_test_stacks_peer", context=context)
        spinning = []  # its /diagnostics come from a timer: the node is in its spin loop once one arrives
        peer.create_subscription(DiagnosticArray, "/diagnostics", lambda m: spinning.extend(
            s for s in m.status if "simulator" in s.name), 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(peer)
        deadline = time.monotonic() + 60
        while not spinning:
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()[-2000:]
            executor.spin_once(timeout_sec=0.1)
        proc.send_signal(signal.SIGUSR1)
        while "most recent call first" not in log.read_text() or "spin_until_done" not in log.read_text():
            assert time.monotonic() < deadline and proc.poll() is None, log.read_text()[-3000:]
            time.sleep(0.05)
        assert proc.poll() is None, "SIGUSR1 ended the node"
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
        executor.shutdown()
        peer.destroy_node()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        rclpy.shutdown(context=context)
    text = log.read_text()
    assert proc.returncode == 0, text[-2000:]
    assert "left the ROS graph with exit code 0" in text
