"""Impacts the COR path cannot use: a free flight that ends on a plate without a fitted free flight after it.

The COR (Eq. 16) needs a fitted flight on each side of the impact. At low excitation or low COR, the
rebound is short: the ball lands, bounces a few frames (a *short flight*, too few frames to fit) or
chatters and sticks (a *contact phase*), and the next fitted flight starts from a launch, not from that
impact. Such a landing is still an impact, and the accelerometers see it. This module finds them so that
they are reported (time, plate, relative approach speed, why there is no COR), never dropped silently.

Rule: for each fitted flight that no COR impact closes (a flight that is not free too: its landing is
reported with that caveat, its speed being approximate), look at what follows its last frame: a
contact cluster then a short flight, a contact phase (cluster longer than an impact), or a fitted flight
that is not free. The landing time is where the flight's parabola relative to the structure reaches the
plate level (the COR impacts' median level of that plate when known, else the median relative position
over the following contact phase, where the ball rests on the plate), searched between the last flight
frame and the end of the first cluster after it; without a level, the middle of the first cluster frame
interval. The plate is given by the sign of the relative velocity at the flight's end (down: bottom).
Units: s, mm, m/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Landing:
    """An impact without a COR at the end of flight ``flight_before``."""

    t_s: float
    plate: str
    v_rel_before_mps: float     # ball minus structure velocity just before the impact (m/s)
    flight_before: int
    reason: str

    def to_dict(self) -> dict:
        return {"t": float(self.t_s), "plate": self.plate, "v_rel_before": float(self.v_rel_before_mps),
                "flight_before": int(self.flight_before), "reason": self.reason}


def _level_from_cluster(cluster, t_s, ball_mm, structure_mm) -> float | None:
    idx = np.asarray(cluster.frames, int)
    if idx.size < 3:
        return None
    y = np.asarray(ball_mm)[idx] - np.asarray(structure_mm)[idx]
    y = y[np.isfinite(y)]
    return float(np.median(y)) if y.size else None


def find_landings(flights, impacts, *, clusters, short_flights, structure, plate_levels: dict, track,
                  max_impact_frames: int) -> list[Landing]:
    """Landings (see module rule) from the streaming fitter's flights, impacts, clusters and short flights;
    ``structure``: the structure's fit; ``plate_levels``: the COR impacts' levels (mm); ``track``: the DIC
    track (times s, ball and structure mm)."""
    t_s = np.asarray(track.t_s, float)
    ball_mm, structure_mm = track.ball_mm, track.structure_mm
    closed = {i.flight_before for i in impacts}
    fitted = sorted(flights, key=lambda f: f.t_start_s)
    clusters = sorted(clusters, key=lambda c: c.t_start_s)
    shorts = sorted(short_flights, key=lambda f: f.t_start_s)
    out: list[Landing] = []
    for k, fl in enumerate(fitted):
        if fl.index in closed:
            continue
        after = [c for c in clusters if c.t_start_s > fl.t_end_s]
        if not after:
            continue                          # the record ends during or right after this flight
        first = after[0]
        nxt_fit = next((f for f in fitted[k + 1:] if f.t_start_s > fl.t_end_s), None)
        nxt_short = next((f for f in shorts if f.t_start_s > fl.t_end_s), None)
        t_next_fit = nxt_fit.t_start_s if nxt_fit is not None else np.inf
        if first.n > max_impact_frames:
            reason = f"followed by a contact phase of {first.n} frames (chatter or sticking): no flight after it"
            rest = first
        elif nxt_short is not None and nxt_short.t_start_s < t_next_fit:
            left = int(np.count_nonzero(t_s > fl.t_end_s))
            if not np.isfinite(t_next_fit) and left <= nxt_short.n_points + max_impact_frames + 1:
                # cut by the end of the take, not by another impact: no chatter is seen
                reason = f"the recording ends {left} frame(s) after it, too few to fit the flight after it"
            else:
                reason = (f"the rebound lasts {nxt_short.n_points} frame(s), too few to fit a flight "
                          "(chatter)")
            rest = next((c for c in after if c.t_start_s > nxt_short.t_start_s and c.n > max_impact_frames), None)
        elif nxt_fit is not None and not nxt_fit.is_free:
            reason = f"the flight after it ({nxt_fit.index}) is not free: {nxt_fit.reason}"
            rest = None
        else:
            continue                          # a COR impact was rejected for another reason (reported there)
        v_end = float(fl.velocity_mps(fl.t_end_s) - structure.velocity_mps(fl.t_end_s))
        plate = "bottom" if v_end < 0 else "top"
        level = plate_levels.get(plate)
        if level is None and rest is not None:
            level = _level_from_cluster(rest, t_s, ball_mm, structure_mm)
        t_hit = None
        if level is not None:
            grid = np.linspace(fl.t_end_s, first.t_end_s, 200)
            rel = fl.position_mm(grid) - structure.position_mm(grid) - level
            cross = np.flatnonzero(np.sign(rel[1:]) != np.sign(rel[:-1]))
            if cross.size:
                j = int(cross[0])
                t_hit = float(grid[j] - rel[j] * (grid[j + 1] - grid[j]) / (rel[j + 1] - rel[j]))
        if t_hit is None:
            i0 = int(first.frames[0])
            t_hit = float(0.5 * (t_s[i0] + t_s[min(i0 + 1, t_s.size - 1)]))
        v_rel = float(fl.velocity_mps(t_hit) - structure.velocity_mps(t_hit))
        if not fl.is_free:
            reason += f"; the flight before is not free ({fl.reason}): time and speed approximate"
        out.append(Landing(t_hit, plate, v_rel, int(fl.index), reason))
    return out
