"""The results document and a DIC track from the fitter's and tracker's messages (for the ``discrepancy``
node), without rclpy: any objects with the fields of vibro_msgs StructureMotion, FreeFlight,
ImpactEstimate and DicFrame will do (an rclpy message or one read from a bag)."""

from __future__ import annotations

import math
from typing import Iterable

import numpy as np

from vibro_io.dictrack import DicTrack
from vibro_model.results import ResultsDocument
from vibro_ros.convert import flight_from_message, impact_from_message, structure_from_message


def document_from_messages(structure, flights: Iterable, impacts: Iterable, recording: str = "graph run"
                           ) -> ResultsDocument:
    """The results document of the fitter's final StructureMotion, FreeFlight and ImpactEstimate messages
    (converted by :mod:`vibro_ros.convert`; flights linked to the impacts that open/close them)."""
    return ResultsDocument.build(recording, structure_from_message(structure), map(flight_from_message, flights),
                                 map(impact_from_message, impacts))


def track_from_messages(frames: Iterable) -> DicTrack:
    """A DicTrack from DicFrame messages (sorted by frame index; lost frames kept with NaN)."""
    rows = sorted(frames, key=lambda m: int(m.frame_index))

    def col(name, dtype=float):
        return np.array([getattr(m, name) for m in rows], dtype=dtype)

    lost = col("lost", bool)
    ball = col("ball_mm")
    struct = col("structure_mm")
    ball[lost] = math.nan
    struct[lost] = math.nan
    return DicTrack(frame=col("frame_index", int), t_s=col("t_s"), ball_mm=ball, structure_mm=struct,
                    ball_valid=col("ball_valid_points", int), structure_valid=col("structure_valid_points", int),
                    ball_zncc=col("ball_mean_zncc"), structure_zncc=col("structure_mean_zncc"), lost=lost)
