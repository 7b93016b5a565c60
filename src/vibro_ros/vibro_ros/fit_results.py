"""Collect the fitter's final results and the DIC frames of a run, for nodes that work on the whole run.

The simulator and discrepancy nodes both need: the structure motion, every *final* free
flight and impact (streamed previews are ignored), and the DIC frames, complete. Complete
means every item the fitter and the tracker announced in their end-of-stream statuses has
arrived, in whatever order DDS delivered them; without the tracker's "dic" status, the
frames count as complete once none has arrived for ``dic_wait_s``. vibro/dic is a latched history,
so a node restarted mid-run receives every frame again; input from another publisher or run, frames
repeated or going back, or a history that does not begin where the stream began stop the node
(vibro_ros.guard). Imports rclpy.
"""

from __future__ import annotations

import time
from typing import Callable

from rclpy.node import Node

from vibro_msgs.msg import DicFrame, FreeFlight, ImpactEstimate, StreamStatus, StructureMotion

from . import topics
from .guard import InputGuard
from .node_support import RESULTS_QOS, history_depth_parameter, history_qos


class FinalFitResults:
    """Subscribes ``node`` to the fitter's results, vibro/dic and vibro/status; calls ``on_update`` on news."""

    def __init__(self, node: Node, on_update: Callable[[], None], dic_wait_s: float = 5.0):
        self.structure: StructureMotion | None = None
        self.flights: dict[int, FreeFlight] = {}
        self.impacts: dict[int, ImpactEstimate] = {}
        self.frames: dict[int, DicFrame] = {}
        self.announced: dict[str, int] = {}
        self.finished: set[str] = set()
        self.dic_wait_s = dic_wait_s
        self._last_dic = time.monotonic()
        self._on_update = on_update
        self.guard = guard = InputGuard(node)
        for topic in (topics.STRUCTURE, topics.FLIGHTS, topics.IMPACTS, topics.DIC):
            guard.watch(topic)
        node.create_subscription(StructureMotion, topics.STRUCTURE.name, self._on_structure, RESULTS_QOS)
        node.create_subscription(FreeFlight, topics.FLIGHTS.name, self._on_flight, RESULTS_QOS)
        node.create_subscription(ImpactEstimate, topics.IMPACTS.name, self._on_impact, RESULTS_QOS)
        node.create_subscription(DicFrame, topics.DIC.name, self._on_dic,
                                 history_qos(history_depth_parameter(node)))
        node.create_subscription(StreamStatus, topics.STATUS.name, self._on_status, RESULTS_QOS)
        node.create_timer(0.5, on_update)  # the dic_wait_s fallback needs a clock, not a message

    def _on_structure(self, msg: StructureMotion) -> None:
        if not self.guard.accept(topics.STRUCTURE.name):
            return
        self.structure = msg
        self._on_update()

    def _on_flight(self, msg: FreeFlight) -> None:
        # streamed flights are previews; the final fit is what counts
        if self.guard.accept(topics.FLIGHTS.name) and msg.final:
            self.flights[msg.index] = msg
            self._on_update()

    def _on_impact(self, msg: ImpactEstimate) -> None:
        if self.guard.accept(topics.IMPACTS.name) and msg.final:
            self.impacts[msg.index] = msg
            self._on_update()

    def _on_dic(self, msg: DicFrame) -> None:
        if not self.guard.accept(topics.DIC.name, run_id=msg.run_id, index=msg.frame_index,
                                 first_index=msg.reference_frame_index, what="frame"):
            return
        self.frames[int(msg.frame_index)] = msg
        self._last_dic = time.monotonic()
        self._on_update()

    def _on_status(self, msg: StreamStatus) -> None:
        if not self.guard.accept(topics.STATUS.name, run_id=msg.run_id):
            return
        if msg.finished:
            self.finished.add(msg.stream)
            if msg.stream in ("impacts", "flights", "dic"):
                self.announced[msg.stream] = int(msg.items_sent)
            self._on_update()

    def complete(self) -> bool:
        """Every announced final flight and impact, the structure fit and all DIC frames have arrived."""
        if not self.guard.ok():
            return False
        if "impacts" not in self.announced or "flights" not in self.announced:
            return False
        if len(self.impacts) < self.announced["impacts"] or len(self.flights) < self.announced["flights"]:
            return False
        if self.structure is None and self.announced["impacts"] > 0:
            return False
        if "dic" in self.announced:
            return len(self.frames) >= self.announced["dic"]
        return time.monotonic() - self._last_dic >= self.dic_wait_s

    def sorted_flights(self) -> list[FreeFlight]:
        return [self.flights[k] for k in sorted(self.flights)]

    def sorted_impacts(self) -> list[ImpactEstimate]:
        return [self.impacts[k] for k in sorted(self.impacts)]

    def unanswered_frames(self) -> list[int]:
        """Frame slots between the reference frame and the last DicFrame received that no DicFrame answered (the
        tracker answers every slot, a lost frame as ``lost``: a slot without an answer is a frame the graph never
        tracked, e.g. sent while a killed tracker was down). The run is then incomplete."""
        if not self.frames:
            return []
        first = min(int(m.reference_frame_index) for m in self.frames.values())
        return sorted(set(range(first, max(self.frames) + 1)) - set(self.frames))

    def incomplete_words(self) -> str:
        """Why the run's results are not judged ("" when every frame slot was answered)."""
        missing = self.unanswered_frames()
        if not missing:
            return ""
        return (f"the run is incomplete: {len(missing)} frame slot(s) without any DIC result ({missing[0]}.."
                f"{missing[-1]}); its simulation and discrepancy are not judged (vibro results marks the run "
                "\"complete\": false)")

    def tracked_frames(self) -> list[DicFrame]:
        """DIC frames that carry a displacement, in frame order."""
        return [self.frames[k] for k in sorted(self.frames) if not self.frames[k].lost]
