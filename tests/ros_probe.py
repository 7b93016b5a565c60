"""A ROS node inside the test process that looks at a running graph from outside, as `ros2` tools do:
which nodes exist, what each publishes and subscribes to, its parameters (through the node's own
parameter service), and what arrives on a topic. Uses its own rclpy context on the domain the
``ros_domain`` fixture chose, and shuts it down on exit.
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from typing import Any, Callable

#: Topics every rclpy node has, whatever its code: not part of a node's vibro interface.
ROS_INFRASTRUCTURE = {"/rosout", "/parameter_events"}


class Probe:
    def __init__(self, name: str = "vibro_test_probe") -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0")),
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received: dict[str, list[Any]] = defaultdict(list)

    def __enter__(self) -> "Probe":
        return self

    def __exit__(self, *exc) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.context)

    def spin(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(deadline - time.monotonic(), 0.0)))

    def spin_until(self, done: Callable[[], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while not done():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def subscribe(self, msg_class: type, topic: str, qos: Any = 10) -> list[Any]:
        """Collect every message of ``topic`` into ``self.received[topic]`` (returned)."""
        self.node.create_subscription(msg_class, topic, self.received[topic].append, qos)
        return self.received[topic]

    def node_names(self) -> set[str]:
        """Fully qualified names of the nodes on the domain."""
        return {(ns.rstrip("/") + "/" + n) for n, ns in self.node.get_node_names_and_namespaces()}

    def wait_for_nodes(self, fqns: list[str], timeout_s: float) -> bool:
        return self.spin_until(lambda: set(fqns) <= self.node_names(), timeout_s)

    def topics_of(self, fqn: str) -> tuple[set[str], set[str]]:
        """(published, subscribed) topic names of the node ``fqn``, without the ROS infrastructure topics."""
        ns, _, name = fqn.rpartition("/")
        ns = ns or "/"
        pubs = {t for t, _ in self.node.get_publisher_names_and_types_by_node(name, ns)}
        subs = {t for t, _ in self.node.get_subscriber_names_and_types_by_node(name, ns)}
        return pubs - ROS_INFRASTRUCTURE, subs - ROS_INFRASTRUCTURE

    def get_parameters(self, fqn: str, names: list[str], timeout_s: float = 20.0) -> dict[str, Any]:
        """Parameter values of the running node ``fqn``, through its ``get_parameters`` service."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python

        client = self.node.create_client(GetParameters, f"{fqn}/get_parameters")
        try:
            if not self.spin_until(client.service_is_ready, timeout_s):
                raise AssertionError(f"{fqn}/get_parameters: no service within {timeout_s} s")
            future = client.call_async(GetParameters.Request(names=names))
            if not self.spin_until(future.done, timeout_s):
                raise AssertionError(f"{fqn}/get_parameters: no answer within {timeout_s} s")
            return {n: parameter_value_to_python(v) for n, v in zip(names, future.result().values)}
        finally:
            self.node.destroy_client(client)
