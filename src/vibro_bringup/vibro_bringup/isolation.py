"""One graph run's identity on a shared ROS domain: a run id, and the namespace its nodes and topics live in.

``vibro graph`` and ``vibro replay`` isolate every run by default: its nodes start in the namespace
``/vibro_<run id>`` (``--namespace NS`` chooses one), so its topics (``/vibro_<id>/vibro/dic``, ...) are
apart from another run's on the same domain, while ``/diagnostics`` stays the one lab-wide topic that
monitoring tools read. Every node also gets the run id as parameter ``run_id`` and refuses messages of
another run (vibro_ros.guard): the second line of defence when two runs are given the same namespace.
A namespace rather than a free ROS_DOMAIN_ID: a lab's tools (rqt, ros2 topic, a rosbag2 recorder)
see and record a run where they already are, and no domain has to be found free.
"""

from __future__ import annotations

import argparse
import re
import uuid
from dataclasses import dataclass

_NAMESPACE = re.compile(r"^/$|^(/[A-Za-z_][A-Za-z0-9_]*)+$")


def namespace_argument(text: str) -> str:
    """``--namespace`` value: a ROS namespace, absolute (a leading ``/`` is added when missing); ``/`` = none."""
    ns = text if text.startswith("/") else f"/{text}"
    if not _NAMESPACE.match(ns):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a ROS namespace (tokens of letters, digits and _, not starting with a digit, "
            "separated by /)")
    return ns


@dataclass(frozen=True)
class RunIdentity:
    """``run_id``: 8 hex digits, new for every run; ``namespace``: absolute ROS namespace of the run's nodes."""

    run_id: str
    namespace: str

    def describe(self, env: dict[str, str]) -> str:
        """One line for the summary: run id, namespace and DDS domain used."""
        domain = env.get("ROS_DOMAIN_ID", "")
        where = f"ROS_DOMAIN_ID {domain}" if domain else "ROS_DOMAIN_ID 0 (unset)"
        return f"run {self.run_id}: namespace {self.namespace}, {where}"


def new_run_identity(namespace: str | None = None) -> RunIdentity:
    """A fresh run id; the namespace is ``namespace`` or ``/vibro_<run id>``."""
    run_id = "r" + uuid.uuid4().hex[:7]  # starts with a letter: never read as a number from a params file
    return RunIdentity(run_id, namespace or f"/vibro_{run_id}")
