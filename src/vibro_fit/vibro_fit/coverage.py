"""Which part of the accelerometer record the video covers (frames that stop early or start late).

A recording whose frames end before its accelerometer data does (the camera's memory filled, frames
deleted) is valid: the filmed part is analysed as usual. But accelerometer impacts outside the filmed
interval cannot be matched to DIC impacts (no flights there), and they are not lost frames either
(the camera never took those frames). This module says so, in numbers, for results.json and the
graph summary. Times are camera time in seconds (DAQ times are converted with the clock offset
t_daq = t_camera + offset_s when it is known, else used as they are).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, kw_only=True)
class FrameCoverage:
    """Filmed interval vs accelerometer interval (camera clock, s) and the accel impacts outside it."""

    frames_start_s: float
    frames_end_s: float
    accel_start_s: float
    accel_end_s: float
    impacts_before_s: list[float] = field(default_factory=list)  # accel impacts before the first frame
    impacts_after_s: list[float] = field(default_factory=list)   # accel impacts after the last frame
    clock_offset_known: bool = True

    @property
    def frames_stop_early(self) -> bool:
        return bool(self.impacts_after_s) or self.accel_end_s > self.frames_end_s + self.slack_s

    @property
    def frames_start_late(self) -> bool:
        return bool(self.impacts_before_s) or self.accel_start_s < self.frames_start_s - self.slack_s

    #: tolerance (s) before a difference in end times is reported: clock offset + a frame interval
    slack_s: float = 0.002

    def message(self) -> str | None:
        """One plain sentence for the user, or None when the video covers the accelerometer record."""
        parts = []
        clock = "" if self.clock_offset_known else " (DAQ clock; camera-to-DAQ offset unknown)"
        if self.frames_stop_early:
            parts.append(f"frames end at t = {self.frames_end_s:.4f} s while the accelerometers run to "
                         f"{self.accel_end_s:.4f} s{clock}: {len(self.impacts_after_s)} accelerometer impact(s) "
                         "after the last frame are not matched to DIC impacts (not filmed; not lost frames)")
        if self.frames_start_late:
            parts.append(f"frames start at t = {self.frames_start_s:.4f} s but the accelerometers at "
                         f"{self.accel_start_s:.4f} s{clock}: {len(self.impacts_before_s)} accelerometer "
                         "impact(s) before the first frame are not matched to DIC impacts")
        return "; ".join(parts) if parts else None

    def to_dict(self) -> dict:
        return {"frames_start_s": self.frames_start_s, "frames_end_s": self.frames_end_s,
                "accel_start_s": self.accel_start_s, "accel_end_s": self.accel_end_s,
                "clock_offset_known": self.clock_offset_known,
                "accel_impacts_before_first_frame": len(self.impacts_before_s),
                "accel_impacts_after_last_frame": len(self.impacts_after_s),
                "accel_impact_times_after_last_frame_s": list(self.impacts_after_s),
                "message": self.message()}


def frame_coverage(frames_t_s, accel_t_s, accel_impact_times_s, clock, frame_interval_s: float) -> FrameCoverage:
    """Compare the frame slots' times (camera clock, s) with the accelerometer samples' and impacts' times
    (DAQ clock, s), put on the camera clock by ``clock`` (anything with ``camera_s(t_daq_s)``: a
    :class:`vibro_fit.accel_impacts.ClockLine`, offset and rate), None when the relation is unknown."""
    ft = np.asarray(frames_t_s, float)
    at = np.asarray(accel_t_s, float)

    def camera(t_daq_s) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t_daq_s, float))
        return t if clock is None else np.atleast_1d(clock.camera_s(t))

    imp = camera(accel_impact_times_s) if len(accel_impact_times_s) else np.empty(0)
    ends = camera([at[0], at[-1]])
    f0, f1 = float(ft[0]), float(ft[-1])
    return FrameCoverage(frames_start_s=f0, frames_end_s=f1, accel_start_s=float(ends[0]),
                         accel_end_s=float(ends[1]),
                         impacts_before_s=[float(x) for x in imp[imp < f0 - 0.5 * frame_interval_s]],
                         impacts_after_s=[float(x) for x in imp[imp > f1 + 0.5 * frame_interval_s]],
                         clock_offset_known=clock is not None, slack_s=2.0 * frame_interval_s)
