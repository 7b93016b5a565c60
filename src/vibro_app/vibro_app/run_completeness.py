"""What a recorded graph run lost: frames without a DIC result, the impacts that may be missing there, restarts.

A graph run answers every frame slot with one DicFrame (a frame that could not be tracked is a *lost* DicFrame,
which the analysis sees and reports like ``vibro analyze`` does). A slot with no DicFrame at all was lost by
the run itself: the tracker was down (killed and restarted), a replayed bag ended early, messages were dropped.
The fitter cannot see impacts in such a gap, so results.json says where the gaps are and how many impacts the
run's own impact rate puts in them; ``complete`` is then false. Plain functions on counts and indices (no
rclpy): :mod:`vibro_app.bag_results` feeds them from a bag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable


@dataclass(frozen=True)
class FrameGap:
    """Frame slots ``first``..``last`` (inclusive, 0-based indices) with no DIC result; times in s (camera)."""

    first: int
    last: int
    t_start_s: float
    t_end_s: float
    reason: str

    @property
    def count(self) -> int:
        return self.last - self.first + 1

    def to_dict(self) -> dict:
        return {"first": self.first, "last": self.last, "count": self.count, "t_start_s": self.t_start_s,
                "t_end_s": self.t_end_s, "reason": self.reason}


@dataclass(frozen=True)
class RunCompleteness:
    """``frames_expected``: frame slots the source announced (None when its end of stream is not recorded);
    ``frames_answered``: slots with a DicFrame; ``gaps``: the slots without one; ``impacts_possibly_missing``:
    the run's impact rate (impacts per s of answered frames) times the gaps' duration; ``restarts``: node name
    -> restarts seen (extra process ids on /diagnostics)."""

    frames_expected: int | None
    frames_answered: int
    gaps: list[FrameGap] = field(default_factory=list)
    impacts_possibly_missing: float = 0.0
    restarts: dict[str, int] = field(default_factory=dict)

    @property
    def frames_missing(self) -> int:
        return sum(g.count for g in self.gaps)

    @property
    def lost_anything(self) -> bool:
        return bool(self.gaps)

    def to_dict(self) -> dict:
        return {"frames_expected": self.frames_expected, "frames_answered": self.frames_answered,
                "frames_missing": self.frames_missing, "gaps": [g.to_dict() for g in self.gaps],
                "impacts_possibly_missing": round(self.impacts_possibly_missing, 1),
                "restarts": dict(sorted(self.restarts.items()))}

    def warnings(self) -> list[str]:
        """One line per gap (where, how long, why, impacts it may hide); one for restarts."""
        out = []
        for g in self.gaps:
            out.append(f"frames {g.first}..{g.last} ({g.count} frame(s), t = {g.t_start_s:.4f}..{g.t_end_s:.4f} s) "
                       f"have no DIC result: {g.reason}; impacts there are not measured")
        if self.gaps:
            out.append(f"{self.frames_missing} of {self.frames_expected or '?'} frames lost by the run: about "
                       f"{self.impacts_possibly_missing:.1f} impact(s) may be missing from the results")
        if self.restarts:
            out.append("restarted mid-run: " + ", ".join(f"{n} x{k}" for n, k in sorted(self.restarts.items())))
        return out


def restarts_from_pids(pids_by_node: dict[str, Iterable[str]]) -> dict[str, int]:
    """Restarts per node from the process ids its /diagnostics carried (one pid: never restarted)."""
    return {name: len(set(pids)) - 1 for name, pids in pids_by_node.items() if len(set(pids)) > 1}


def _runs(indices: list[int]) -> list[tuple[int, int]]:
    """Consecutive runs ``(first, last)`` of sorted distinct ``indices``."""
    runs: list[tuple[int, int]] = []
    for k in indices:
        if runs and k == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], k)
        else:
            runs.append((k, k))
    return runs


def run_completeness(answered: dict[int, float], frames_expected: int | None, first_index: int = 0, *,
                     impacts: int = 0, restarts: dict[str, int] | None = None, source_lost: int = 0,
                     source_name: str = "frame source") -> RunCompleteness:
    """The completeness of a run whose DicFrames answered the frame slots ``answered`` (index -> camera time, s).

    ``frames_expected``: slots the source announced at its end (sent + unreadable; None: no end of stream
    recorded, then the slots up to the last answered one are expected); ``first_index``: the DIC reference
    frame (slots before it are not the tracker's to answer); ``impacts``: impacts measured in the run;
    ``source_lost``: frames the source itself could not give (a replayed bag cut short: those slots are gaps
    with that reason); times of unanswered slots from the answered frames' spacing (fps).
    """
    restarts = dict(restarts or {})
    keys = sorted(answered)
    end = frames_expected if frames_expected is not None else (keys[-1] + 1 if keys else first_index)
    missing = sorted(set(range(first_index, end)) - set(keys))
    if len(keys) >= 2:
        dt = (answered[keys[-1]] - answered[keys[0]]) / (keys[-1] - keys[0])
        t_ref, k_ref = answered[keys[0]], keys[0]
    else:
        dt, t_ref, k_ref = math.nan, math.nan, 0
    tracker_restarts = restarts.get("dic_tracker", 0)
    gaps = []
    for first, last in _runs(missing):
        if last >= end - source_lost and source_lost:
            reason = f"the {source_name} could not give them ({source_lost} frame(s) announced lost at its end)"
        elif tracker_restarts:
            reason = f"dic_tracker restarted {tracker_restarts}x mid-run: frames sent while it was down"
        elif not keys or first > keys[-1]:
            reason = "the run ended before they were tracked (no DicFrame after the last one recorded)"
        else:
            reason = "no DicFrame recorded for them (dropped between the tracker and the recorder, or never tracked)"
        gaps.append(FrameGap(first, last, t_ref + (first - k_ref) * dt, t_ref + (last - k_ref) * dt, reason))
    answered_s = len(keys) * dt  # the time the run did see (gaps excluded): the impact rate is measured there
    rate = impacts / answered_s if math.isfinite(answered_s) and answered_s > 0 else 0.0
    missing_s = sum(g.count for g in gaps) * (dt if math.isfinite(dt) else 0.0)
    return RunCompleteness(frames_expected, len(keys), gaps, rate * missing_s, restarts)
