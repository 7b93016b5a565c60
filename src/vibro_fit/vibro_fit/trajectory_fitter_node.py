"""ROS node ``trajectory_fitter``: DIC frames (+ accelerometer blocks) in; structure motion, flights and
per-impact COR out.

While frames stream in, :class:`vibro_fit.streaming.StreamingFitter` publishes each impact
estimate as soon as the flight after it has been fitted (one flight of latency) and each
closed flight (``final = false``). When the tracker (and the accelerometer source) announce the end of their
streams, the node runs :func:`vibro_fit.identify.identify` on everything received, the very
function ``vibro analyze`` calls, and publishes the final structure motion, flights and
impacts; a final estimate replaces the streamed one with the same index. So the graph's
results equal the offline CLI's on the same recording.

After identify() the node runs ``vibro analyze``'s cross-checks (:func:`vibro_fit.cross_checks.consistency_checks`:
time base, physical plausibility, accelerometer drive tone and plates) and carries their section on its
/diagnostics status (values ``consistency`` and, on a refusal, ``refused``: vibro_ros.topics.CONSISTENCY_KEY),
where ``vibro results`` reads it from the bag. A refusal (e.g. COR outside [0, 1] with rig.yaml's
excitation.frequency_hz wrong) refuses the run as analyze does: the final structure motion and flights are
published (friction withheld when it is the implausible part), no final impact, the impacts stream ends with them
counted lost, and once the readers have acknowledged it the node exits with code 2 and the refusal as one line
(vibro_bringup.exit_policy: the run ends).

Live accelerometers (``live_accel``: a DAQ driver publishes vibro/accel, docs/live.md): every block is checked
as the impact detector checks it (:class:`vibro_fit.live_accel.BlockCheck`, a refusal stops the node), blocks are
not kept (a live stream has no end), the impacts are detected here with the same core as ``impact_detector`` and
put on the camera clock with the camera-to-DAQ offset from the blocks' lab-clock stamps, refined from the impacts
both see as ``vibro analyze`` refines it, with the DAQ clock's rate when it drifts significantly
(:class:`vibro_fit.live_accel.LiveClockOffset`); they mark the frames next to them as contact
(``StreamingFitter.push_accel_impact``). /diagnostics: ``clock_offset_s`` (at camera time ``clock_t_ref_s``),
``clock_rate_ppm`` (0 unless significant), its source, the stamps' offset and jitter, ``accel_impacts_count``,
lost blocks and samples.

Restart: vibro/dic and vibro/accel are latched histories, so a fitter restarted mid-run receives every
DicFrame and block again and reaches the same final results. A history that does not begin where its
stream began (frame ``reference_frame_index``, block 0), no accelerometer block at all when they are
expected, or input from another publisher or run stops the node with an error (vibro_ros.guard),
never a run with fewer impacts.
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np
from rclpy.node import Node
from rclpy.task import Future

from vibro_io.accel import AccelData
from vibro_io.dictrack import DicTrack, FrameTrack
from vibro_io.rig import load_rig
from vibro_model.assemble import StageOutputs, assemble_results
from vibro_model.constants import G_MPS2
from vibro_model.errors import RecordingError
from vibro_model.results import ResultsDocument
from vibro_msgs.msg import AccelBlock, DicFrame, FreeFlight, ImpactEstimate, StreamStatus, StructureMotion
from vibro_ros import topics
from vibro_ros.adaptive_qos import results_subscription
from vibro_ros.convert import flight_to_message, frame_track_from_message, impact_to_message, structure_to_message
from vibro_ros.guard import InputGuard
from vibro_ros.node_support import (
    RESULTS_QOS,
    Health,
    StatusPublisher,
    cpu_nice_parameter,
    declare,
    history_depth_parameter,
    history_qos,
    run_node,
    time_origin_parameter,
)
from vibro_ros.readiness import ReaderGate

from .accel_impacts import AccelImpactDetector, warm_up
from .cross_checks import consistency_checks, consistency_section
from .flight_fit import FlightFit
from .identify import METHODS, identify
from .impacts import ImpactFit
from .live_accel import LIVE_RATE_GUESS_HZ, AccelStreamRefused, BlockCheck, LiveClockOffset
from .plausibility import consistency_stage
from .results import identified_stage
from .segmentation import segmentation_config
from .streaming import StreamingFitter


def flight_message(fl: FlightFit, mass_kg: float, final: bool = False, origin_ns: int = 0,
                   g_axis_mps2: float = G_MPS2) -> FreeFlight:
    """A fitted flight as published (``final``: the end-of-stream fit), stamped at its last frame on the lab
    clock of ``origin_ns``; its friction (Eq. 17) against the gravity along the axis ``g_axis_mps2``."""
    return flight_to_message(fl.model(mass_kg, g_axis_mps2), final, origin_ns)


def impact_message(est: ImpactFit, final: bool = False, origin_ns: int = 0) -> ImpactEstimate:
    """An impact estimate as published (``final``: the end-of-stream estimate), stamped at the impact on the
    lab clock of ``origin_ns``."""
    return impact_to_message(est.model(), final, origin_ns)


class TrajectoryFitter(Node):
    def __init__(self) -> None:
        super().__init__("trajectory_fitter")
        rig_file = declare(self, "rig_file", "", "rig.yaml of the recording")
        self.method = declare(self, "method", "paper", f"impact method: {' or '.join(METHODS)}")
        self.use_accel = bool(declare(self, "use_accelerometers", True,
                                      "wait for vibro/accel and refine impacts with the accelerometers"))
        weights = declare(self, "weights", "none", "flight fit weights: none or dic_valid")
        self.stream_wait_s = float(declare(self, "stream_wait_s", 5.0,
                                           "after a stream is announced finished, wait this long for missing "
                                           "items, then finish without them (they are reported lost)"))
        self.live_accel = bool(declare(self, "live_accel", False,
                                       "true: vibro/accel comes from a DAQ driver (docs/live.md): blocks are checked, "
                                       "not kept, and their impacts mark the streamed flights' ends"))
        accel_rate = float(declare(self, "accel_rate_hz", 0.0, "live: the DAQ's sample rate (Hz); a block at another "
                                                                "rate is refused (0 = the first block's rate)"))
        self.offset_tol_s = float(declare(self, "clock_offset_tol_s", 0.0005,
                                          "live: an accelerometer and a DIC impact this close (s, after the stamps' "
                                          "offset) are one impact when the offset is refined"))
        if not rig_file:
            raise RecordingError("trajectory_fitter: parameter 'rig_file' is required")
        if self.method not in METHODS:
            raise RecordingError(f"trajectory_fitter: parameter 'method' must be one of {METHODS}")
        if weights not in ("none", "dic_valid"):
            raise RecordingError("trajectory_fitter: parameter 'weights' must be none or dic_valid")
        self.weights = None if weights == "none" else weights
        self.rig = load_rig(rig_file)
        self.time_origin_ns = time_origin_parameter(self)
        cpu_nice_parameter(self)
        self.block_check = BlockCheck(accel_rate, self.time_origin_ns) if self.live_accel and self.use_accel else None
        if self.block_check is not None:  # before the subscriptions: a driver seeing them matched finds it warm
            warm_up(accel_rate or LIVE_RATE_GUESS_HZ)
        self.clock = LiveClockOffset(self.offset_tol_s)
        self.accel_detector: AccelImpactDetector | None = None
        self.stream = StreamingFitter(self.rig.excitation.frequency_hz,
                                      method="paper" if self.method == "joint" else self.method,
                                      config=segmentation_config(self.rig))
        self.rows: list[FrameTrack] = []
        self.blocks: dict[int, AccelBlock] = {}
        self.dic_announced: int | None = None
        self.accel_announced: int | None = None
        self.done_final = False
        self._announced_at: float | None = None
        self._last_block_at = 0.0
        self.health = Health(self)
        self.health.rate_counter = "frames"
        self.status = StatusPublisher(self, "impacts")
        self.flights_status = StatusPublisher(self, "flights")
        self.pub_structure = self.create_publisher(StructureMotion, topics.STRUCTURE.name, RESULTS_QOS)
        self.pub_flights = self.create_publisher(FreeFlight, topics.FLIGHTS.name, RESULTS_QOS)
        self.pub_impacts = self.create_publisher(ImpactEstimate, topics.IMPACTS.name, RESULTS_QOS)
        self.guard = InputGuard(self)
        history = history_qos(history_depth_parameter(self))
        self.guard.watch(topics.DIC)
        self.create_subscription(DicFrame, topics.DIC.name, self._on_dic, history)
        if self.use_accel:
            self.guard.watch(topics.ACCEL)
            results_subscription(self, AccelBlock, topics.ACCEL.name, self._on_block, history)
        results_subscription(self, StreamStatus, topics.STATUS.name, self._on_status)
        self.create_timer(0.5, self._maybe_finish)
        self.gate = ReaderGate(self, health=self.health)  # exits once its readers have the final outputs
        self.refusal: str | None = None  # the cross-checks' refusal (one line), set by the final pass
        self.done = Future()  # the gate's, or a refusal once the readers have what was published (exit code 2)
        self.gate.done.add_done_callback(self._gate_done)

    # ---------------------------------------------------------------- streaming
    def _on_dic(self, msg: DicFrame) -> None:
        if not self.guard.accept(topics.DIC.name, run_id=msg.run_id, index=msg.frame_index,
                                 first_index=msg.reference_frame_index, what="frame"):
            return
        k = int(msg.frame_index)
        expected = len(self.rows)
        if k > expected:  # frames the tracker never answered (e.g. it restarted): a visible gap
            self.health.count("gap_frames", k - expected)
            self.health.warn(f"no DIC result for frames {expected}..{k - 1}")
            self.get_logger().warning(f"no DIC result for frames {expected}..{k - 1}; treated as lost")
            for gap in range(expected, k):
                t = self.rig.camera.frame_time_s(gap)
                self._push(FrameTrack(frame=gap, t_s=t, ball_mm=math.nan, structure_mm=math.nan, ball_valid=0,
                                      structure_valid=0, ball_zncc=math.nan, structure_zncc=math.nan, lost=True))
        self._push(frame_track_from_message(msg))  # the tracker's row as published, ball rotation included
        self.health.observe(msg.t_s)
        self._maybe_finish()

    def _push(self, row: FrameTrack) -> None:
        self.rows.append(row)
        self.health.count("frames")
        for est in self.stream.push(row):
            self.pub_impacts.publish(impact_message(est, origin_ns=self.time_origin_ns))
            self.health.count("streamed_impacts")
            if self.block_check is not None:
                self.clock.add_dic(est.t_s)
                self._report_clock()
        for fl in self.stream.pop_flights():
            self.pub_flights.publish(flight_message(fl, self.rig.ball.mass_kg, origin_ns=self.time_origin_ns,
                                                    g_axis_mps2=self.rig.g_axis_mps2))

    def _on_block(self, msg: AccelBlock) -> None:
        live = self.block_check is not None
        if not self.guard.accept(topics.ACCEL.name, run_id=msg.run_id, index=msg.block_index,
                                 first_index=None if live else 0, what="block"):
            return
        if live:
            self._on_live_block(msg)
            return
        self.blocks[int(msg.block_index)] = msg
        self._last_block_at = time.monotonic()
        self._maybe_finish()

    def _on_live_block(self, msg: AccelBlock) -> None:
        """A DAQ driver's block: checked, its impacts detected and put on the camera clock for the streaming fit."""
        try:
            verdict = self.block_check.check_block(msg)
        except AccelStreamRefused as exc:
            self.guard.fail(f"{topics.ACCEL.name}: {exc}")
            return
        for w in verdict.warnings:
            self.health.warn(w)
        if verdict.lost_blocks:
            self.health.count("accel_blocks_lost", verdict.lost_blocks)
        if verdict.lost_samples:
            self.health.count("accel_samples_lost", verdict.lost_samples)
        found = []
        if verdict.restart and self.accel_detector is not None:  # no high-pass across a discontinuity
            found += self.accel_detector.finish()
            self.accel_detector = AccelImpactDetector(msg.sample_rate_hz, self.rig.excitation.frequency_hz,
                                                      threshold=self.accel_detector.threshold)
        if self.accel_detector is None:
            self.accel_detector = AccelImpactDetector(msg.sample_rate_hz, self.rig.excitation.frequency_hz)
        t = msg.t_start_s + np.arange(len(msg.upper_ms2)) / msg.sample_rate_hz
        found += self.accel_detector.push_block(t, msg.upper_ms2, msg.lower_ms2)
        self.clock.stamps_s = self.block_check.stamp_offset_s
        for imp in found:
            self.clock.add_accel(imp.t_s)
            self.health.count("accel_impacts")
        if found:
            self.clock.refine()
        for imp in found:
            self.stream.push_accel_impact(self.clock.to_camera_s(imp.t_s))
        self._last_block_at = time.monotonic()
        self._report_clock()

    def _report_clock(self) -> None:
        offset = self.clock.offset_s
        self.health.values["clock_offset_s"] = "" if offset is None else f"{offset:.7f}"
        self.health.values["clock_offset_source"] = self.clock.source
        self.health.values["clock_rate_ppm"] = f"{self.clock.rate_ppm:.2f}"
        self.health.values["clock_t_ref_s"] = f"{self.clock.t_ref_s:.6f}"
        stamps = self.block_check.stamp_offset_s
        self.health.values["clock_offset_from_stamps_s"] = "" if stamps is None else f"{stamps:.7f}"
        self.health.values["stamp_jitter_s"] = f"{self.block_check.stamp_jitter_s:.7f}"

    def _on_status(self, msg: StreamStatus) -> None:
        if not self.guard.accept(topics.STATUS.name, run_id=msg.run_id):
            return
        if msg.finished and msg.stream == "dic":
            self.dic_announced = int(msg.items_sent)
        elif msg.finished and msg.stream == "accel":
            self.accel_announced = int(msg.items_sent)
        self._maybe_finish()

    # ---------------------------------------------------------------- final pass
    def _ready(self) -> bool:
        """Every announced frame and block has arrived, or the wait for stragglers has run out."""
        need_accel = self.use_accel and self.rig.accelerometers is not None
        if self.dic_announced is None:
            return False
        complete = len(self.rows) >= self.dic_announced and (
            not need_accel or (self.accel_announced is not None and len(self.blocks) >= self.accel_announced))
        if complete:
            return True
        # the DIC stream has ended: wait (bounded) for stragglers, and for the accelerometer source's
        # end-of-stream status, which a source that has already exited cannot repeat
        if self._announced_at is None:
            self._announced_at = time.monotonic()
        quiet_since = max(self._announced_at, self._last_block_at)  # accelerometer blocks still flowing: wait
        if time.monotonic() - quiet_since < self.stream_wait_s:
            return False
        if need_accel and not self.blocks:
            self.guard.fail("no accelerometer block ever arrived on vibro/accel although use_accelerometers is "
                            "true and rig.yaml has accelerometers (source not running, or this node was restarted "
                            "after the source and its history had gone); set use_accelerometers:=false to fit "
                            "without them")
            return False
        missing_frames = max(0, self.dic_announced - len(self.rows))
        missing_blocks = max(0, (self.accel_announced or 0) - len(self.blocks)) if need_accel else 0
        msg = (f"streams ended but {missing_frames} DIC frame(s) and {missing_blocks} accelerometer block(s) "
               f"never arrived after {self.stream_wait_s:g} s; finishing without them")
        if need_accel and self.accel_announced is None:
            msg = (f"the DIC stream ended but the accelerometer end-of-stream status never arrived after "
                   f"{self.stream_wait_s:g} s; finishing with the {len(self.blocks)} block(s) received "
                   f"and {missing_frames} DIC frame(s) missing")
        self.health.warn(msg)
        self.get_logger().warning(msg)
        for gap in range(len(self.rows), self.dic_announced):  # the missing tail, as lost rows
            t = self.rig.camera.frame_time_s(gap)
            self._push(FrameTrack(frame=gap, t_s=t, ball_mm=math.nan, structure_mm=math.nan, ball_valid=0,
                                  structure_valid=0, ball_zncc=math.nan, structure_zncc=math.nan, lost=True))
        return True

    def _accel(self) -> AccelData | None:
        if not self.use_accel or not self.blocks:
            return None
        order = sorted(self.blocks)
        missing = sorted(set(range(order[-1] + 1)) - set(order))
        if missing:
            self.health.warn(f"accelerometer blocks missing: {missing[:5]}")
            self.get_logger().warning(f"accelerometer blocks missing ({len(missing)}): impacts there are not seen")
        t = np.concatenate([b.t_start_s + np.arange(len(b.upper_ms2)) / b.sample_rate_hz
                            for b in (self.blocks[i] for i in order)])
        up = np.concatenate([np.asarray(self.blocks[i].upper_ms2) for i in order])
        lo = np.concatenate([np.asarray(self.blocks[i].lower_ms2) for i in order])
        return AccelData(t, up, lo)

    def _gate_done(self, gate_done: Future) -> None:
        if gate_done.exception() is not None:
            self.done.set_exception(gate_done.exception())
        elif self.refusal is not None:  # run_node logs it as the node's last line and exits with code 2
            self.done.set_exception(RecordingError(self.refusal))
        else:
            self.done.set_result(gate_done.result())

    def _maybe_finish(self) -> None:
        if self.done_final or not self.guard.ok() or not self._ready():
            return
        self.done_final = True
        for est in self.stream.finish():
            self.pub_impacts.publish(impact_message(est, origin_ns=self.time_origin_ns))
        track = DicTrack.from_frames(self.rows)
        accel = self._accel()
        try:
            ident = identify(track, self.rig, accel, method=self.method, weights=self.weights)
            track = ident.corrected_track(track)   # the track as identified (its sub-pixel bias taken out)
            findings, evidence = consistency_checks(ident, track, self.rig, accel, f"the frames on {topics.DIC.name}")
        except RecordingError as exc:
            self.health.error(str(exc))
            self.get_logger().error(f"identification failed: {exc}")
            self.flights_status.publish(0, 0, True)
            self.status.publish(0, 0, True)
            self.gate.finish()
            return
        # vibro analyze's cross-checks, the same core: the bag's reader finds them on /diagnostics
        section = consistency_section(findings, evidence)
        self.health.values[topics.CONSISTENCY_KEY] = json.dumps(section)
        for f in findings:
            if not f.refuses:
                self.get_logger().warning(f"consistency: {f.message}")
        for w in ident.warnings:
            self.get_logger().warning(w)
        # what is published is the assembler's document (vibro analyze's rules: a refusal withholds the impacts,
        # and the friction when it is the implausible part)
        stages = StageOutputs(recording=f"the frames on {topics.DIC.name}", identified=identified_stage(ident),
                              consistency=consistency_stage(findings, section))
        refused = stages.consistency.refusal is not None
        self._publish_final(assemble_results(stages), float(track.t_s[-1]) if len(track.t_s) else None,
                            with_impacts=not refused)
        if refused:
            self._refuse(stages.consistency.refusal, len(ident.impacts))
            return
        self.get_logger().info(f"final: {len(ident.flights)} flights, {len(ident.impacts)} impacts, "
                               f"regime {ident.regime.name}")
        self.gate.finish()

    def _publish_final(self, document: ResultsDocument, t_end_s: float | None, *, with_impacts: bool) -> None:
        """The final pass's structure, flights and (``with_impacts``: the run is not refused) impacts with their
        end-of-stream statuses (a refused run's impacts stream ends in :meth:`_refuse`)."""
        self.pub_structure.publish(structure_to_message(document.structure, t_end_s, self.time_origin_ns,
                                                        document.sections.get("drive"),
                                                        document.sections.get("dic_bias"),
                                                        document.sections.get("plate_motion")))
        for flight in document.flights:
            self.pub_flights.publish(flight_to_message(flight, True, self.time_origin_ns))
        self.flights_status.publish(len(document.flights), 0, True)
        if not with_impacts:
            return
        for impact in document.impacts:
            self.pub_impacts.publish(impact_to_message(impact, final=True, origin_ns=self.time_origin_ns))
        self.status.publish(len(document.impacts), 0, True)

    def _refuse(self, message: str, withheld: int) -> None:
        """A cross-check refused the identification (as ``vibro analyze`` refuses it): no final impact is
        published, the impacts stream ends with the ``withheld`` impacts counted lost, /diagnostics carries the
        error and the consistency section at once, and the node exits with code 2 (one line, the refusal) once
        its readers have acknowledged what was published (the structure and flights), without keeping its
        history for restarted readers: a refusal ends the run (vibro_bringup.exit_policy)."""
        self.refusal = (f"{message} (results withheld: the final impacts are not published; the impacts stream "
                        f"ends with {withheld} counted lost)")
        self.get_logger().error(self.refusal)
        self.health.error(self.refusal)
        self.health.values[topics.REFUSED_KEY] = self.refusal
        self.health.publish()
        self.status.publish(0, withheld, True)
        self.gate.finish(always=True, keep_history=False)  # live too: a refusal ends the run


def main(args: list[str] | None = None) -> int:
    return run_node(TrajectoryFitter, args)


if __name__ == "__main__":
    sys.exit(main())
