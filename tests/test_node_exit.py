"""How a node's own process ends (vibro_ros.entry.exit_now, vibro_ros.node_support.keep_node_objects_until_exit)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

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
