"""A bag's results: a complete final pass replaces the streamed previews whole.

The fitter streams a preview of each impact as it happens, then its final pass (the same identification as
vibro analyze) republishes every flight and impact with final = true and announces how many on vibro/status.
The final pass may number them differently (short hops measured as one chain, landings): a preview at an index
the final pass does not use is not a result, and must not be kept beside it. When the final pass is cut short
(fewer final messages than announced), the previews are all there is for the missing indices.
"""

from __future__ import annotations

from pathlib import Path

from rclpy.serialization import serialize_message

from vibro_msgs.msg import ImpactEstimate, StreamStatus, StructureMotion


def _bag(path: Path, *, streamed: list[int], final: list[int], announced: int | None) -> Path:
    from vibro_ros.bags import BagWriter

    writer = BagWriter(path)
    messages = [("/vibro/structure", "vibro_msgs/msg/StructureMotion", StructureMotion(amplitude_mm=1.0))]
    messages += [("/vibro/impacts", "vibro_msgs/msg/ImpactEstimate",
                  ImpactEstimate(index=k, plate="bottom", cor=0.5, final=False)) for k in streamed]
    messages += [("/vibro/impacts", "vibro_msgs/msg/ImpactEstimate",
                  ImpactEstimate(index=k, plate="bottom", cor=0.7, final=True)) for k in final]
    if announced is not None:
        messages.append(("/vibro/status", "vibro_msgs/msg/StreamStatus",
                         StreamStatus(stream="impacts", items_sent=announced, finished=True)))
    for stamp, (topic, kind, msg) in enumerate(messages, start=1):
        writer.add_topic(topic, kind)
        writer.write(topic, stamp, serialize_message(msg))
    writer.close()
    return path


def _indices(bag: Path) -> dict[int, float]:
    from vibro_app.bag_results import BagResults
    from vibro_ros import topics

    return {int(m.index): float(m.cor) for m in BagResults(bag).merged(topics.IMPACTS.name)}


def test_a_complete_final_pass_drops_previews_it_does_not_number(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "b", streamed=[0, 1, 2, 3, 4], final=[0, 1, 2], announced=3)
    assert _indices(bag) == {0: 0.7, 1: 0.7, 2: 0.7}


def test_a_final_pass_cut_short_keeps_the_previews_of_what_it_misses(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "b", streamed=[0, 1, 2, 3, 4], final=[0, 1], announced=3)
    assert _indices(bag) == {0: 0.7, 1: 0.7, 2: 0.5, 3: 0.5, 4: 0.5}
    bag = _bag(tmp_path / "c", streamed=[0, 1, 2], final=[], announced=None)  # no final pass at all
    assert _indices(bag) == {0: 0.5, 1: 0.5, 2: 0.5}
