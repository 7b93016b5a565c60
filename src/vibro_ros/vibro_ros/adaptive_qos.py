"""Subscriptions that adapt to what the publishers on a topic offer.

Two needs, one DDS rule (a transient-local reader never matches a volatile writer):

- vibro's result topics are published reliable + transient local, so a node or recorder
  that starts late still gets every result; but a replay tool or driver that publishes the
  same topic volatile must still be heard. rmw's ``BEST_AVAILABLE`` durability does not
  do it: it is decided once, when the subscription is created, from the publishers the
  new node has discovered by then (in a fresh process: none, which gives transient local),
  so a volatile publisher is rejected in every start order (tests/test_bags_rosbag2.py).
  :class:`ResultsSubscription` keeps a transient-local reader (late-joiner history) and,
  once a publisher it cannot match is discovered, adds a volatile (best-effort if needed)
  reader that matches everyone; a sample both readers get is delivered once (recognised by
  its serialized bytes: rclpy's EventsExecutor cannot hand message info, i.e. writer
  timestamp and sequence number, to a callback).
- the recorder requests, per topic, what rosbag2's recorder requests
  (:func:`vibro_ros.qos_format.adapt_request_to_offers`) and stores the offered profiles.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from typing import Any, Callable
from weakref import WeakKeyDictionary

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from .qos_format import OfferedProfile
from .qos_format import profile_dict as _profile_dict

#: How often a ResultsSubscription looks for publishers it cannot match (s).
POLL_S = 0.5

#: node -> the ResultsSubscriptions it holds, checked by one timer per node (a timer each cost the recorder
#: 12 executor wake-ups a second, each rebuilding the wait set)
_POLLED: "WeakKeyDictionary[Node, list[ResultsSubscription]]" = WeakKeyDictionary()


def _poll_publishers_of(node: Node) -> None:
    for sub in list(_POLLED.get(node, ())):
        sub._check_publishers()


def profile_dict(qos: QoSProfile) -> dict[str, Any]:
    """An rclpy QoS profile in rosbag2's version-9 layout (policy names, ``{sec, nsec}`` durations)."""
    return _profile_dict(OfferedProfile(history=qos.history.name.lower(), depth=qos.depth,
                                        reliability=qos.reliability.name.lower(),
                                        durability=qos.durability.name.lower(),
                                        deadline_ns=qos.deadline.nanoseconds, lifespan_ns=qos.lifespan.nanoseconds,
                                        liveliness=qos.liveliness.name.lower(),
                                        liveliness_lease_ns=qos.liveliness_lease_duration.nanoseconds,
                                        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions))


def discovered_offers(node: Node, topic: str, declared: QoSProfile | None = None,
                      declared_publishers: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """Profiles offered by the publishers of ``topic`` that ``node`` has discovered, rosbag2-style.

    DDS discovery carries reliability, durability, deadline, lifespan and liveliness but not
    history and depth (they come back as ``unknown``/0, as rosbag2 records them). For a
    publisher that is one of vibro's own (node name in ``declared_publishers``, or any name
    when it is empty) and whose reliability and durability are the ``declared`` profile's,
    history and depth are taken from ``declared``: the table its node publishes with.
    """
    offers = []
    for info in node.get_publishers_info_by_topic(node.resolve_topic_name(topic)):
        offer = profile_dict(info.qos_profile)
        if (declared is not None and (not declared_publishers or info.node_name in declared_publishers)
                and offer["reliability"] == declared.reliability.name.lower()
                and offer["durability"] == declared.durability.name.lower()):
            offer["history"] = declared.history.name.lower()
            offer["depth"] = int(declared.depth)
        offers.append(offer)
    return offers


#: node name rmw reports for an endpoint whose node is not known yet (its ros_discovery_info lags DDS discovery)
UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"


def publishers_identified(node: Node, topic: str) -> bool:
    """Whether the node of every discovered publisher of ``topic`` is known by name yet."""
    return all(info.node_name not in ("", UNKNOWN_NODE_NAME)
               for info in node.get_publishers_info_by_topic(node.resolve_topic_name(topic)))


def matches(request: QoSProfile, offer: dict[str, Any]) -> bool:
    """Whether a reader with ``request`` matches a writer offering ``offer`` (reliability, durability)."""
    if request.reliability == ReliabilityPolicy.RELIABLE and offer["reliability"] != "reliable":
        return False
    if request.durability == DurabilityPolicy.TRANSIENT_LOCAL and offer["durability"] != "transient_local":
        return False
    return True


class ResultsSubscription:
    """A transient-local subscription that also hears volatile and best-effort publishers.

    ``callback(msg)`` gets each sample once (``raw``: its serialized bytes). ``profile`` is
    the request (vibro's RESULTS_QOS, or the recorder's adapted one); the companion reader,
    added when a publisher the request cannot match is discovered, has the same depth,
    volatile durability, and best effort if any publisher is best effort. While two readers
    run, a sample byte-identical to one of the last ``2 * depth`` (at least 1000) is taken
    for the second copy and dropped; vibro's messages carry stamps and indices, so two
    distinct ones are never identical.
    """

    def __init__(self, node: Node, msg_type, topic: str, callback: Callable[[Any], None], profile: QoSProfile,
                 raw: bool = False):
        self._node = node
        self._msg_type = msg_type
        self._topic = topic
        self._callback = callback
        self._profile = profile
        self._raw = raw
        self._seen: OrderedDict[bytes, None] = OrderedDict()
        self._keep = max(2 * int(profile.depth), 1000)
        self.subscriptions = [self._subscribe(profile)]
        self.companion_profile: QoSProfile | None = None
        if node not in _POLLED:
            _POLLED[node] = []
            node.create_timer(POLL_S, lambda: _poll_publishers_of(node))
        _POLLED[node].append(self)

    def _subscribe(self, profile: QoSProfile):
        """A reader with ``profile``. A publisher it cannot match is what the companion reader is for: rmw's
        default warning ("offering incompatible QoS. No messages will be received from it") would tell a lab
        the opposite of what happens, so the event adapts at once instead (the companion logs what it hears)."""
        from rclpy.event_handler import SubscriptionEventCallbacks

        events = SubscriptionEventCallbacks(incompatible_qos=lambda _info: self._check_publishers())
        return self._node.create_subscription(self._msg_type, self._topic, self._on_message, profile, raw=True,
                                              event_callbacks=events)

    @property
    def topic_name(self) -> str:
        return self.subscriptions[0].topic_name

    def _on_message(self, data: bytes) -> None:
        key = hashlib.blake2b(data, digest_size=16).digest()
        if key in self._seen and len(self.subscriptions) > 1:  # the other reader's copy of this sample
            return
        self._seen[key] = None
        if len(self._seen) > self._keep:
            self._seen.popitem(last=False)
        self._callback(data if self._raw else deserialize_message(data, self._msg_type))

    def _check_publishers(self) -> None:
        offers = discovered_offers(self._node, self._topic)
        strangers = [o for o in offers if not matches(self._profile, o)]
        if not strangers:
            return
        best_effort = any(o["reliability"] != "reliable" for o in offers)
        if self.companion_profile is not None and (
                not best_effort or self.companion_profile.reliability == ReliabilityPolicy.BEST_EFFORT):
            return
        companion = QoSProfile(history=self._profile.history, depth=self._profile.depth,
                               reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE,
                               durability=DurabilityPolicy.VOLATILE)
        self._node.get_logger().info(
            f"{self.topic_name}: {len(strangers)} publisher(s) offer "
            f"{', '.join(sorted({o['reliability'] + '/' + o['durability'] for o in strangers}))}; "
            f"also subscribing {companion.reliability.name.lower()}/volatile")
        self.subscriptions.append(self._subscribe(companion))
        if self.companion_profile is not None:  # upgrade reliable -> best effort: the old companion goes
            self._node.destroy_subscription(self.subscriptions.pop(1))
        self.companion_profile = companion


def results_subscription(node: Node, msg_type, topic: str, callback: Callable[[Any], None],
                         profile: QoSProfile | None = None) -> ResultsSubscription:
    """Subscribe to a vibro result topic: late-joiner history from transient-local publishers,
    and every sample of volatile ones (see :class:`ResultsSubscription`)."""
    from .node_support import RESULTS_QOS

    return ResultsSubscription(node, msg_type, topic, callback, profile or RESULTS_QOS)
