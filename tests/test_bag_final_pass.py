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


def _bag(path: Path, *, streamed: list[int], final: list[int], announced: int | None, lost: int = 0,
         fitter_values: dict[str, str] | None = None, discrepancy_values: dict[str, str] | None = None) -> Path:
    from vibro_ros.bags import BagWriter

    writer = BagWriter(path)
    messages = [("/vibro/structure", "vibro_msgs/msg/StructureMotion", StructureMotion(amplitude_mm=1.0))]
    messages += [("/vibro/impacts", "vibro_msgs/msg/ImpactEstimate",
                  ImpactEstimate(index=k, plate="bottom", cor=0.5, final=False)) for k in streamed]
    messages += [("/vibro/impacts", "vibro_msgs/msg/ImpactEstimate",
                  ImpactEstimate(index=k, plate="bottom", cor=0.7, final=True)) for k in final]
    if announced is not None:
        messages.append(("/vibro/status", "vibro_msgs/msg/StreamStatus",
                         StreamStatus(stream="impacts", items_sent=announced, items_lost=lost, finished=True)))
    for node, values in (("/trajectory_fitter", fitter_values), ("/discrepancy", discrepancy_values)):
        if values is not None:  # the node's /diagnostics status
            from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

            status = DiagnosticStatus(name=node, values=[KeyValue(key=k, value=v) for k, v in values.items()])
            messages.append(("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", DiagnosticArray(status=[status])))
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


def test_impacts_a_fitter_withheld_make_the_run_incomplete_even_without_its_diagnostics(tmp_path: Path) -> None:
    """A refused run: the fitter publishes no final impact and announces them lost. Read from a bag that did not
    record /diagnostics (where the refusal's words are), the document still says something is missing, and keeps
    none of the previews as a result."""
    from vibro_app.bag_results import document_from_bag

    doc = document_from_bag(_bag(tmp_path / "b", streamed=[0, 1, 2], final=[], announced=0, lost=3))
    assert doc.complete is False and doc.impacts == []
    assert any("3 vibro/impacts message(s) announced lost by their publisher" in w for w in doc.warnings), doc.warnings


def test_a_consistency_value_that_is_not_vibros_section_is_said_not_dropped(tmp_path: Path) -> None:
    """The fitter's cross-checks travel as a JSON value on /diagnostics; one that does not parse as the section
    (a foreign or damaged bag) is named in a warning, and a refusal recorded beside it still refuses."""
    from vibro_app.bag_results import document_from_bag
    from vibro_ros import topics

    for i, bad in enumerate(("{not json", "[1, 2]", '{"findings": "none"}')):
        doc = document_from_bag(_bag(tmp_path / f"b{i}", streamed=[0], final=[0], announced=1,
                                     fitter_values={topics.CONSISTENCY_KEY: bad}))
        assert any("is not a consistency section" in w for w in doc.warnings), doc.warnings
        assert "consistency" not in doc.sections
    doc = document_from_bag(_bag(tmp_path / "r", streamed=[0], final=[], announced=0, lost=1,
                                 fitter_values={topics.CONSISTENCY_KEY: "{not json",
                                                topics.REFUSED_KEY: "COR outside [0, 1]"}))
    assert doc.sections["consistency"]["refused"] is True and doc.impacts == [] and doc.complete is False
    assert doc.warnings[0] == "refused: COR outside [0, 1]"


def test_the_discrepancy_nodes_section_is_read_and_a_damaged_one_said(tmp_path: Path) -> None:
    """The discrepancy node carries results.json's discrepancy section and its local-structure impacts on
    /diagnostics; read whole when they parse, each named in a warning when it does not (never read as nothing)."""
    import json

    from vibro_app.bag_results import document_from_bag
    from vibro_ros import topics

    section = {"baseline_deviation": 0.0123, "findings": [], "final_deviation": 0.0123, "noise_floor": {"x": 1.0}}
    doc = document_from_bag(_bag(tmp_path / "a", streamed=[0], final=[0], announced=1,
                                 discrepancy_values={topics.DISCREPANCY_KEY: json.dumps(section),
                                                     topics.LOCAL_STRUCTURE_KEY: "[]"}))
    assert doc.discrepancy.baseline_deviation == 0.0123 and doc.discrepancy.details == {"noise_floor": {"x": 1.0}}
    for i, (section_text, local_text) in enumerate((("{not json", '[{"t_paper_s": "soon"}]'),
                                                    ('{"findings": "none"}', "[1, 2]"))):
        doc = document_from_bag(_bag(tmp_path / f"b{i}", streamed=[0], final=[0], announced=1,
                                     discrepancy_values={topics.DISCREPANCY_KEY: section_text,
                                                         topics.LOCAL_STRUCTURE_KEY: local_text}))
        assert doc.discrepancy.baseline_deviation is None
        assert any(f"value '{topics.DISCREPANCY_KEY}' could not be read" in w for w in doc.warnings), doc.warnings
        assert any(f"value '{topics.LOCAL_STRUCTURE_KEY}' could not be read" in w for w in doc.warnings), doc.warnings
