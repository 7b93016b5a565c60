"""One converter each way between the results types of :mod:`vibro_model.results` and their vibro_msgs.

| model | message |
|---|---|
| StructureMotion | vibro_msgs/StructureMotion |
| Flight | vibro_msgs/FreeFlight |
| Impact | vibro_msgs/ImpactEstimate |
| SimulationRun | vibro_msgs/SimulationResult |
| DiscrepancyFinding | vibro_msgs/DiscrepancyFinding |
| FrameTrack / DicTrack (vibro_io.dictrack) | vibro_msgs/DicFrame |

Messages carry mm (``*_mm``, ``*_mm_per_s``) and m/s (``*_m_per_s``) as their field names say; the model
is SI. An unknown number is None in the model and NaN in a float64 field. ``*_from_message`` read any
object with the message's fields (an rclpy message, a rosbags-deserialised one from a bag) and import
no ROS; ``*_to_message`` build rclpy messages (vibro_msgs imported on use). A FreeFlight carries the
first/last fitted frame only: the impacts that open/close a flight are linked again from the impacts
(:func:`vibro_model.results.link_impacts`, done by ``ResultsDocument.build``).
"""

from __future__ import annotations

import json
import math
from typing import Any, Iterable, Mapping

import numpy as np

from vibro_io.dictrack import DicTrack, FrameTrack
from vibro_model.codec import json_value, nan_if_none, none_if_nan
from vibro_model.errors import RecordingError
from vibro_model.results import DiscrepancyFinding, Flight, Impact, SimulationRun, StructureMotion
from vibro_model.units import m_to_mm, mm_to_m


def _stamp(msg: Any, t_s: float | None, origin_ns: int) -> Any:
    """Stamp ``msg.header`` with data time ``t_s`` on the lab clock of ``origin_ns`` (vibro_ros.lab_clock);
    an unknown time (None, NaN) leaves the stamp at 0."""
    if t_s is not None and np.isfinite(t_s):
        from .node_support import stamp_from_seconds

        stamp_from_seconds(msg.header, t_s, origin_ns)
    return msg


# ---------------------------------------------------------------- DIC frames
def frame_track_to_message(row: FrameTrack, mesh_points: tuple[int, int], status: str = "",
                           reference_frame_index: int = 0, run_id: str = "", origin_ns: int = 0):
    """The DicFrame of one tracked frame (mm, rad; ``mesh_points``: ball, structure mesh sizes), stamped at its
    camera time ``row.t_s`` on the lab clock of ``origin_ns``."""
    from vibro_msgs.msg import DicFrame

    msg = DicFrame(frame_index=row.frame, t_s=row.t_s, ball_mm=row.ball_mm, structure_mm=row.structure_mm,
                   ball_valid_points=row.ball_valid, structure_valid_points=row.structure_valid,
                   ball_mesh_points=mesh_points[0], structure_mesh_points=mesh_points[1],
                   ball_mean_zncc=row.ball_zncc, structure_mean_zncc=row.structure_zncc,
                   lost=row.lost, status=status, reference_frame_index=reference_frame_index, run_id=run_id,
                   ball_rot_rad=float(row.ball_rot_rad), ball_rot_std_rad=float(row.ball_rot_std_rad))
    msg.header.frame_id = "camera"
    return _stamp(msg, row.t_s, origin_ns)


def carries_ball_rotation(msg: Any) -> bool:
    """Whether a DicFrame has the ball rotation fields at all (a bag recorded before they existed decodes
    without them)."""
    return hasattr(msg, "ball_rot_rad") and hasattr(msg, "ball_rot_std_rad")


def ball_rotation_from_message(msg: Any) -> tuple[float, float]:
    """(rotation rad, its 1-sigma rad) of a DicFrame; NaN, NaN when the message has no such fields, or both are
    exactly 0 (the ROS default a publisher that does not measure rotation leaves: a fit's sigma is never 0)."""
    if not carries_ball_rotation(msg):
        return math.nan, math.nan
    rot, std = float(msg.ball_rot_rad), float(msg.ball_rot_std_rad)
    if rot == 0.0 and std == 0.0:
        return math.nan, math.nan
    return rot, std


def frame_track_from_message(msg: Any) -> FrameTrack:
    """The tracked frame of a DicFrame, numbers as the tracker published them (a lost frame's too: ``lost`` says
    not to use them); rotation as :func:`ball_rotation_from_message`."""
    rot_rad, rot_std_rad = ball_rotation_from_message(msg)
    return FrameTrack(frame=int(msg.frame_index), t_s=float(msg.t_s), ball_mm=float(msg.ball_mm),
                      structure_mm=float(msg.structure_mm), ball_valid=int(msg.ball_valid_points),
                      structure_valid=int(msg.structure_valid_points), ball_zncc=float(msg.ball_mean_zncc),
                      structure_zncc=float(msg.structure_mean_zncc), lost=bool(msg.lost), ball_rot_rad=rot_rad,
                      ball_rot_std_rad=rot_std_rad)


def dic_track_from_messages(frames: Iterable[Any]) -> DicTrack:
    """A DicTrack from DicFrame messages, in frame order (lost frames kept, flagged; a frame index received twice
    counts once, the last one received)."""
    by_index = {int(m.frame_index): m for m in frames}
    return DicTrack.from_frames(frame_track_from_message(by_index[k]) for k in sorted(by_index))


# ---------------------------------------------------------------- structure
def structure_to_message(s: StructureMotion, stamp_s: float | None = None, origin_ns: int = 0,
                         drive: Mapping[str, Any] | None = None, dic_bias: Mapping[str, Any] | None = None,
                         plate_motion: Mapping[str, Any] | None = None):
    """A StructureMotion message of the identified sine, the identification's windowed ``drive`` (results.json's
    ``drive`` section, carried as JSON in ``drive_json``), the DIC sub-pixel bias it took out (``dic_bias``,
    in ``dic_bias_json``) and each plate's motion against the structure (``plate_motion``, in
    ``plate_motion_json``); each empty when None."""
    from vibro_msgs.msg import StructureMotion as Msg

    msg = Msg(amplitude_mm=nan_if_none(m_to_mm(s.amplitude_m)), frequency_hz=nan_if_none(s.frequency_hz),
              phase_rad=nan_if_none(s.phase_rad), offset_mm=nan_if_none(m_to_mm(s.offset_m)),
              amplitude_std_mm=nan_if_none(m_to_mm(s.amplitude_std_m)),
              frequency_std_hz=nan_if_none(s.frequency_std_hz), phase_std_rad=nan_if_none(s.phase_std_rad),
              offset_std_mm=nan_if_none(m_to_mm(s.offset_std_m)),
              rms_residual_mm=nan_if_none(m_to_mm(s.rms_residual_m)), frames_used=int(s.n_points or 0),
              ball_offset_mm=nan_if_none(m_to_mm(s.ball_offset_m)),
              drive_json=json.dumps(json_value(drive), allow_nan=False) if drive is not None else "",
              dic_bias_json=json.dumps(json_value(dic_bias), allow_nan=False) if dic_bias is not None else "",
              plate_motion_json=(json.dumps(json_value(plate_motion), allow_nan=False)
                                 if plate_motion is not None else ""))
    return _stamp(msg, stamp_s, origin_ns)


def _json_section(msg: Any, name: str) -> dict[str, Any] | None:
    """The results section a StructureMotion message carries as JSON in field ``name`` (None: not known, or a bag
    recorded before the field existed). Raises RecordingError naming the field when its JSON is damaged or not an
    object."""
    text = getattr(msg, name, "") or ""
    if not text:
        return None
    try:
        section = json.loads(text)
    except ValueError as exc:
        raise RecordingError(f"StructureMotion.{name} is not valid JSON ({exc})") from None
    if not isinstance(section, dict):
        raise RecordingError(f"StructureMotion.{name} must hold a JSON object, got {type(section).__name__}")
    return section


def drive_from_message(msg: Any) -> dict[str, Any] | None:
    """The windowed drive section a StructureMotion message carries (:func:`_json_section`)."""
    return _json_section(msg, "drive_json")


def dic_bias_from_message(msg: Any) -> dict[str, Any] | None:
    """The DIC sub-pixel bias section a StructureMotion message carries (:func:`_json_section`)."""
    return _json_section(msg, "dic_bias_json")


def plate_motion_from_message(msg: Any) -> dict[str, Any] | None:
    """The plates' motion section a StructureMotion message carries (:func:`_json_section`)."""
    return _json_section(msg, "plate_motion_json")


def structure_sections(msg: Any) -> dict[str, dict[str, Any]]:
    """The results sections a StructureMotion message carries (``drive``, ``dic_bias``, ``plate_motion``: those
    it holds)."""
    sections = {"drive": drive_from_message(msg), "dic_bias": dic_bias_from_message(msg),
                "plate_motion": plate_motion_from_message(msg)}
    return {name: value for name, value in sections.items() if value is not None}


def structure_from_message(msg: Any) -> StructureMotion:
    return StructureMotion(amplitude_m=mm_to_m(none_if_nan(msg.amplitude_mm)),
                           frequency_hz=none_if_nan(msg.frequency_hz),
                           phase_rad=none_if_nan(msg.phase_rad), offset_m=mm_to_m(none_if_nan(msg.offset_mm)),
                           rms_residual_m=mm_to_m(none_if_nan(msg.rms_residual_mm)),
                           amplitude_std_m=mm_to_m(none_if_nan(msg.amplitude_std_mm)),
                           frequency_std_hz=none_if_nan(msg.frequency_std_hz),
                           phase_std_rad=none_if_nan(msg.phase_std_rad),
                           offset_std_m=mm_to_m(none_if_nan(msg.offset_std_mm)), n_points=int(msg.frames_used),
                           ball_offset_m=mm_to_m(none_if_nan(msg.ball_offset_mm)))


# ---------------------------------------------------------------- flights
def flight_to_message(f: Flight, final: bool = False, origin_ns: int = 0):
    """A FreeFlight stamped at its last fitted frame; ``final``: the end-of-stream fit."""
    from vibro_msgs.msg import FreeFlight

    msg = FreeFlight(index=int(f.index), t_start_s=nan_if_none(f.t_first_frame_s),
                     t_end_s=nan_if_none(f.t_last_frame_s), a_mm_per_s2=nan_if_none(m_to_mm(f.a_mps2)),
                     b_mm_per_s=nan_if_none(m_to_mm(f.b_mps)), c_mm=nan_if_none(m_to_mm(f.c_m)),
                     direction=f.direction, friction_n=nan_if_none(f.friction_n),
                     friction_std_n=nan_if_none(f.friction_std_n),
                     rms_residual_mm=nan_if_none(m_to_mm(f.rms_residual_m)), points_used=int(f.n_points or 0),
                     fitted=bool(f.free), note=f.reason, final=bool(final))
    return _stamp(msg, f.t_last_frame_s, origin_ns)


def flight_from_message(msg: Any) -> Flight:
    return Flight(index=int(msg.index), t_first_frame_s=none_if_nan(msg.t_start_s),
                  t_last_frame_s=none_if_nan(msg.t_end_s),
                  a_mps2=mm_to_m(none_if_nan(msg.a_mm_per_s2)), b_mps=mm_to_m(none_if_nan(msg.b_mm_per_s)),
                  c_m=mm_to_m(none_if_nan(msg.c_mm)), direction=str(msg.direction),
                  friction_n=none_if_nan(msg.friction_n),
                  friction_std_n=none_if_nan(msg.friction_std_n),
                  rms_residual_m=mm_to_m(none_if_nan(msg.rms_residual_mm)), n_points=int(msg.points_used),
                  free=bool(msg.fitted), reason=str(msg.note))


# ---------------------------------------------------------------- impacts
def impact_to_message(i: Impact, final: bool = False, origin_ns: int = 0):
    """An ImpactEstimate stamped at the impact time; ``final``: the end-of-stream estimate."""
    from vibro_msgs.msg import ImpactEstimate

    msg = ImpactEstimate(index=int(i.index), t_s=nan_if_none(i.t_s), t_std_s=nan_if_none(i.t_std_s), plate=i.plate,
                         cor=nan_if_none(i.cor), cor_std=nan_if_none(i.cor_std),
                         v_ball_before_m_per_s=nan_if_none(i.v_ball_before_mps),
                         v_ball_after_m_per_s=nan_if_none(i.v_ball_after_mps),
                         v_structure_m_per_s=nan_if_none(i.v_structure_mps), flight_before=int(i.flight_before),
                         flight_after=int(i.flight_after), final=bool(final),
                         cor_std_model=nan_if_none(i.cor_std_model))
    return _stamp(msg, i.t_s, origin_ns)


def impact_from_message(msg: Any) -> Impact:
    return Impact(index=int(msg.index), t_s=none_if_nan(msg.t_s), plate=str(msg.plate), cor=none_if_nan(msg.cor),
                  cor_std=none_if_nan(msg.cor_std),
                  v_ball_before_mps=none_if_nan(msg.v_ball_before_m_per_s),
                  v_ball_after_mps=none_if_nan(msg.v_ball_after_m_per_s),
                  v_structure_mps=none_if_nan(msg.v_structure_m_per_s), t_std_s=none_if_nan(msg.t_std_s),
                  flight_before=int(msg.flight_before),
                  flight_after=int(msg.flight_after),
                  cor_std_model=none_if_nan(getattr(msg, "cor_std_model", math.nan)))


# ---------------------------------------------------------------- simulation
def simulation_run_to_message(run: SimulationRun, stamp_s: float | None = None, origin_ns: int = 0):
    from vibro_msgs.msg import SimulationResult

    msg = SimulationResult(model=run.model, deviation=nan_if_none(run.deviation), impacts=int(run.n_impacts or 0))
    msg.t_s = np.asarray(run.t_s, dtype=float).tolist()
    msg.ball_mm = m_to_mm(np.asarray(run.ball_m, dtype=float)).tolist()
    msg.measured_ball_mm = m_to_mm(np.asarray(run.measured_ball_m, dtype=float)).tolist()
    return _stamp(msg, stamp_s, origin_ns)


def simulation_run_from_message(msg: Any) -> SimulationRun:
    return SimulationRun(str(msg.model), none_if_nan(msg.deviation), int(msg.impacts),
                         np.asarray(msg.t_s, dtype=float), mm_to_m(np.asarray(msg.ball_mm, dtype=float)),
                         mm_to_m(np.asarray(msg.measured_ball_mm, dtype=float)))


# ---------------------------------------------------------------- discrepancy findings
def finding_to_message(finding: DiscrepancyFinding, index: int, stamp_s: float | None = None,
                       origin_ns: int = 0):
    """Finding number ``index`` of a run (parameters as parallel name/value/std arrays, NaN when unknown)."""
    from vibro_msgs.msg import DiscrepancyFinding as Msg

    stds = finding.parameters_std or {}
    msg = Msg(index=int(index), effect=finding.effect, where=finding.where)
    msg.parameter_names = list(finding.parameters)
    msg.parameter_values = [nan_if_none(v) for v in finding.parameters.values()]
    msg.parameter_std = [nan_if_none(stds.get(k)) for k in finding.parameters]
    msg.deviation_before = nan_if_none(finding.deviation_before)
    msg.deviation_after = nan_if_none(finding.deviation_after)
    return _stamp(msg, stamp_s, origin_ns)


def finding_from_message(msg: Any) -> DiscrepancyFinding:
    """The finding (its number is ``msg.index``); a finding without parameters has no ``parameters_std``."""
    names = [str(n) for n in msg.parameter_names]
    return DiscrepancyFinding(str(msg.effect), {n: none_if_nan(v) for n, v in zip(names, msg.parameter_values)},
                              str(msg.where), none_if_nan(msg.deviation_before), none_if_nan(msg.deviation_after),
                              {n: none_if_nan(v) for n, v in zip(names, msg.parameter_std)} if names else None)
