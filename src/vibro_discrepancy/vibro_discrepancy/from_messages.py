"""The results document and a DIC track from the fitter's and tracker's messages (for the ``discrepancy``
node), without rclpy: any objects with the fields of vibro_msgs StructureMotion, FreeFlight,
ImpactEstimate and DicFrame will do (an rclpy message or one read from a bag)."""

from __future__ import annotations

import math
from typing import Iterable

from vibro_io.dictrack import DicTrack
from vibro_model.assemble import Identified, StageOutputs, assemble_results
from vibro_model.results import ResultsDocument
from vibro_ros.convert import (
    dic_track_from_messages,
    flight_from_message,
    impact_from_message,
    structure_from_message,
    structure_sections,
)


def stages_from_messages(structure, flights: Iterable, impacts: Iterable, recording: str = "graph run"
                         ) -> StageOutputs:
    """The identification stage of the fitter's final StructureMotion, FreeFlight and ImpactEstimate messages
    (converted by :mod:`vibro_ros.convert`), as the results assembler takes it; the windowed drive the
    StructureMotion carries is its ``drive`` section, the DIC sub-pixel bias its ``dic_bias`` section. Raises
    RecordingError when their JSON is damaged."""
    identified = Identified(structure=structure_from_message(structure),
                            flights=list(map(flight_from_message, flights)),
                            impacts=list(map(impact_from_message, impacts)),
                            sections=structure_sections(structure))
    return StageOutputs(recording=recording, identified=identified)


def document_from_messages(structure, flights: Iterable, impacts: Iterable, recording: str = "graph run"
                           ) -> ResultsDocument:
    """The results document of the fitter's final messages (:func:`stages_from_messages`; flights linked to the
    impacts that open/close them), by the one assembler (:func:`vibro_model.assemble.assemble_results`)."""
    return assemble_results(stages_from_messages(structure, flights, impacts, recording))


def track_from_messages(frames: Iterable) -> DicTrack:
    """A DicTrack from DicFrame messages (:func:`vibro_ros.convert.dic_track_from_messages`; lost frames kept
    with NaN displacements)."""
    track = dic_track_from_messages(frames)
    track.ball_mm[track.lost] = math.nan
    track.structure_mm[track.lost] = math.nan
    return track
