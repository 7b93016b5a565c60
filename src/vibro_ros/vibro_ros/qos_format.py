"""QoS profiles as rosbag2 (ROS 2 Jazzy, metadata version 9) stores them, and its recorder's QoS rule.

rosbag2 keeps, per topic, the QoS profiles the publishers *offered* (one entry per
publisher, as discovered). With metadata version 9 a profile is a mapping with policy
names as strings (``keep_last``, ``reliable``, ``transient_local``, ``automatic``, ...)
and durations as ``{sec, nsec}`` (``RMW_DURATION_INFINITE`` = 9223372036 s 854775807 ns).
metadata.yaml holds the list as YAML; the MCAP channel's ``offered_qos_profiles`` entry
holds the same list dumped to a YAML string. ``ros2 bag play`` offers what was recorded,
so a transient-local topic is replayed transient local.

No rclpy here: converting an rclpy ``QoSProfile`` is :func:`vibro_ros.adaptive_qos.profile_dict`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

import yaml

#: rmw's "infinite" duration, as rosbag2 writes it (the default deadline, lifespan and lease).
DURATION_INFINITE_NS = 9223372036 * 1_000_000_000 + 854775807

HISTORY = ("system_default", "keep_last", "keep_all", "unknown")
RELIABILITY = ("system_default", "reliable", "best_effort", "unknown", "best_available")
DURABILITY = ("system_default", "transient_local", "volatile", "unknown", "best_available")
LIVELINESS = ("system_default", "automatic", "manual_by_topic", "unknown", "best_available")


def duration_dict(ns: int) -> dict[str, int]:
    """``{sec, nsec}`` of a duration in nanoseconds (rmw_time_t as rosbag2 writes it)."""
    ns = min(int(ns), DURATION_INFINITE_NS)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


@dataclass(frozen=True, kw_only=True)
class OfferedProfile:
    """One publisher's offered QoS, by rosbag2's policy names; durations in ns (default: infinite).

    Attributes
    ----------
    history : str
        One of :data:`HISTORY`.
    depth : int
        History depth (messages).
    reliability : str
        One of :data:`RELIABILITY`.
    durability : str
        One of :data:`DURABILITY`.
    deadline_ns, lifespan_ns : int
        Deadline and lifespan (ns).
    liveliness : str
        One of :data:`LIVELINESS`.
    liveliness_lease_ns : int
        Liveliness lease duration (ns).
    avoid_ros_namespace_conventions : bool
        The profile's avoid_ros_namespace_conventions flag.
    """

    history: str
    depth: int
    reliability: str
    durability: str
    deadline_ns: int = DURATION_INFINITE_NS
    lifespan_ns: int = DURATION_INFINITE_NS
    liveliness: str = "automatic"
    liveliness_lease_ns: int = DURATION_INFINITE_NS
    avoid_ros_namespace_conventions: bool = False


def profile_dict(profile: OfferedProfile) -> dict[str, Any]:
    """One offered profile in rosbag2's version-9 layout (keys in rosbag2's order); ValueError for a policy name
    rosbag2 does not know."""
    history, reliability, durability = profile.history, profile.reliability, profile.durability
    liveliness = profile.liveliness
    for value, allowed, what in ((history, HISTORY, "history"), (reliability, RELIABILITY, "reliability"),
                                 (durability, DURABILITY, "durability"), (liveliness, LIVELINESS, "liveliness")):
        if value not in allowed:
            raise ValueError(f"QoS {what} {value!r}: must be one of {', '.join(allowed)}")
    return {
        "history": history,
        "depth": int(profile.depth),
        "reliability": reliability,
        "durability": durability,
        "deadline": duration_dict(profile.deadline_ns),
        "lifespan": duration_dict(profile.lifespan_ns),
        "liveliness": liveliness,
        "liveliness_lease_duration": duration_dict(profile.liveliness_lease_ns),
        "avoid_ros_namespace_conventions": bool(profile.avoid_ros_namespace_conventions),
    }


def dump_profiles(profiles: list[dict]) -> str:
    """The MCAP channel metadata string: the profile list as block YAML (empty string for none)."""
    if not profiles:
        return ""
    return yaml.safe_dump(list(profiles), sort_keys=False, default_flow_style=False).strip()


def parse_profiles(value: str | list | None, where: str) -> list[dict]:
    """Offered profiles from metadata.yaml (a list) or a channel entry (a YAML string); ValueError naming ``where``."""
    if value in (None, ""):
        return []
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ValueError(f"{where}: offered_qos_profiles is not YAML ({exc})") from None
    if not isinstance(value, list) or not all(isinstance(p, dict) for p in value):
        raise ValueError(f"{where}: offered_qos_profiles must be a list of QoS mappings")
    return value


def adapt_request_to_offers(offers: Iterable[dict]) -> tuple[str, str]:
    """(reliability, durability) a recorder requests so it matches every offering publisher.

    rosbag2's rule: reliable only if every publisher is reliable, else best effort (so a
    best-effort camera is recorded); transient local only if every publisher is transient
    local (so latched results are received), else volatile. No offers: reliable, volatile.
    """
    offers = list(offers)
    if not offers:
        return "reliable", "volatile"
    reliability = "reliable" if all(o["reliability"] == "reliable" for o in offers) else "best_effort"
    durability = "transient_local" if all(o["durability"] == "transient_local" for o in offers) else "volatile"
    return reliability, durability
