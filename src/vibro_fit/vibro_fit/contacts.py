"""Contact phases: the ball riding a plate, found from the track's positions.

The acceleration rule of :mod:`vibro_fit.segmentation` flags a frame whose ball acceleration is not -g. A
ball riding a plate moves with the plate, and while the plate's acceleration is near -g (just before it
releases the ball) the riding frames look like flight: they would be fitted into the next flight's
parabola. A riding ball is seen by its *position* instead: ball minus structure stays on the plate's level.

Rule (positions mm, track coordinates y_rel = ball - structure; sigma_rel the noise of y_rel, ball and
structure noise in quadrature):

1. The plate's level: the median y_rel of the COR impacts on it when known (:func:`plate_levels`), else the
   extreme of y_rel (bottom: the low end, a ball cannot go below its plate; top: the high end): the
   median y_rel over the runs of at least ``min_frames`` consecutive frames within 2 ``k_sigma`` sigma_rel
   of the 0.5th (99.5th) percentile. A top level is accepted only from impacts, or when it lies 2b (the
   free play) above a known bottom level within 10 % (a flat apex of the flight is not a plate).
2. A contact phase is a run of at least ``min_frames`` consecutive good frames with
   |y_rel - level| <= ``k_sigma`` sigma_rel. A flight passes the level in one frame or two (an impact at
   0.05 m/s moves 50 um between frames), a ball riding the plate stays on it.
3. ``first_frame_s``/``last_frame_s`` are the first and last frame of the run. Hops lower than k_sigma
   sigma_rel (the end of a chatter sequence, a fraction of a frame long) are inside the phase: on the track
   they are contact.
4. :func:`refine_contacts` gives the physical start and end (``start_s``, ``end_s``, and how, in
   ``start_from``/``end_from``). Start: when hops measured on the plate (:mod:`vibro_fit.hops`) land just
   before the run, the accumulation point of the chatter that follows, each hop e times the one before
   (e the last measured COR): t_land + T_last e / (1 - e), kept when it lies between the landing and three
   frames into the run. End: the ball leaves the plate when the plate's acceleration falls below the
   ball's free acceleration (the free flights' median, -g without other forces): the crossing of the
   structure fit's acceleration within the run's last 8 frames (the ball's separation grows with the
   cube of the time after it, so the run's last frame is a few frames late).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

K_SIGMA = 4.0
MIN_FRAMES = 5


@dataclass(frozen=True, kw_only=True)
class ContactPhase:
    """The ball riding ``plate`` from the frame at ``start_s`` to the frame at ``end_s`` (camera clock, s)."""

    start_s: float
    end_s: float
    plate: str
    first: int            # track index of the first frame
    last: int             # track index of the last frame
    n_frames: int
    level_mm: float       # the plate's level (ball - structure, track coordinates)
    first_frame_s: float = math.nan
    last_frame_s: float = math.nan
    start_from: str = "first frame on the plate"
    end_from: str = "last frame on the plate"

    def to_dict(self) -> dict:
        return {"start_s": float(self.start_s), "end_s": float(self.end_s), "plate": self.plate,
                "n_frames": int(self.n_frames), "level_mm": float(self.level_mm),
                "first_frame_s": float(self.first_frame_s), "last_frame_s": float(self.last_frame_s),
                "start_from": self.start_from, "end_from": self.end_from}


def _runs(mask: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """(first, last) positions of the runs of True at least ``min_len`` long."""
    out = []
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(int))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    for a, b in zip(starts, ends):
        if b - a + 1 >= min_len:
            out.append((int(a), int(b)))
    return out


def _extreme_level(r: np.ndarray, sigma: float, side: int, k: float, min_frames: int) -> float | None:
    """The level of the runs at the low (side -1) or high (+1) extreme of ``r`` (rule 1), or None."""
    edge = float(np.percentile(r, 0.5 if side < 0 else 99.5))
    near = (r <= edge + 2 * k * sigma) if side < 0 else (r >= edge - 2 * k * sigma)
    runs = _runs(near, min_frames)
    if not runs:
        return None
    return float(np.median(np.concatenate([r[a:b + 1] for a, b in runs])))


def find_contacts(track, sigma_rel_mm: float, free_play_mm: float, levels: dict | None = None,
                  k_sigma: float = K_SIGMA, min_frames: int = MIN_FRAMES) -> list[ContactPhase]:
    """Contact phases (module rule) of a DIC track (times s, ball and structure mm, good frames); ``levels``:
    plate levels from the impacts (:func:`vibro_fit.segmentation.plate_levels`), used where known."""
    t_s, ball_mm, structure_mm, good = track.t_s, track.ball_mm, track.structure_mm, track.good
    levels = levels or {}
    idx = np.flatnonzero(np.asarray(good, bool))
    if idx.size < min_frames or not np.isfinite(sigma_rel_mm) or sigma_rel_mm <= 0:
        return []
    t = np.asarray(t_s, float)
    r = np.asarray(ball_mm, float)[idx] - np.asarray(structure_mm, float)[idx]
    k = k_sigma
    found: dict[str, float] = {}
    bottom = levels.get("bottom")
    if bottom is None:
        bottom = _extreme_level(r, sigma_rel_mm, -1, k, min_frames)
    if bottom is not None:
        found["bottom"] = float(bottom)
    top = levels.get("top")
    if top is None:
        cand = _extreme_level(r, sigma_rel_mm, +1, k, min_frames)
        if cand is not None and bottom is not None and abs(cand - bottom - 2 * free_play_mm) <= 0.2 * free_play_mm:
            top = cand
    if top is not None:
        found["top"] = float(top)
    out: list[ContactPhase] = []
    for plate, level in found.items():
        for a, b in _runs(np.abs(r - level) <= k * sigma_rel_mm, min_frames):
            first, last = int(idx[a]), int(idx[b])
            out.append(ContactPhase(start_s=float(t[first]), end_s=float(t[last]), plate=plate, first=first, last=last,
                                    n_frames=b - a + 1, level_mm=level,
                                    first_frame_s=float(t[first]), last_frame_s=float(t[last])))
    return sorted(out, key=lambda c: c.start_s)


def contact_frames(contacts: list[ContactPhase], good: np.ndarray) -> set[int]:
    """Track indices of the good frames inside the contact phases."""
    g = np.asarray(good, bool)
    out: set[int] = set()
    for c in contacts:
        out.update(int(i) for i in range(c.first, c.last + 1) if g[i])
    return out


def refine_contacts(contacts: list[ContactPhase], chains, structure, free_accel_mps2: float | None,
                    frame_dt_s: float) -> list[ContactPhase]:
    """Physical start and end of each contact phase (rule 4). ``chains``: :class:`vibro_fit.hops.HopChain`
    list; ``structure``: a fit with ``acceleration_mps2(t)``; ``free_accel_mps2``: the ball's acceleration
    in free flight (None: the end stays the last frame)."""
    out = []
    for c in contacts:
        upd = {}
        before = [h for h in chains if h.plate == c.plate and h.landing_s is not None
                  and h.impacts and c.first_frame_s - 4 * frame_dt_s <= h.landing_s <= c.first_frame_s + frame_dt_s]
        if before:
            h = max(before, key=lambda x: x.landing_s)
            e = float(h.impacts[-1].cor)
            if 0.0 < e < 0.95 and h.last_hop_s:
                ts = h.landing_s + h.last_hop_s * e / (1.0 - e)
                if h.landing_s <= ts <= c.first_frame_s + 3 * frame_dt_s:
                    upd.update(start_s=float(ts), start_from=(
                        f"accumulation of the chatter after the hop landing at {h.landing_s:.5f} s "
                        f"(last hop {1e3 * h.last_hop_s:.2f} ms, COR {e:.3f})"))
        if free_accel_mps2 is not None and np.isfinite(free_accel_mps2):
            sgn = 1.0 if c.plate == "bottom" else -1.0
            grid = np.linspace(c.last_frame_s - 8 * frame_dt_s, c.last_frame_s + frame_dt_s, 400)
            f = sgn * (np.asarray(structure.acceleration_mps2(grid), float) - free_accel_mps2)
            cross = np.flatnonzero((f[:-1] > 0) & (f[1:] <= 0))
            if cross.size:
                j = int(cross[-1])
                tr = float(grid[j] - f[j] * (grid[j + 1] - grid[j]) / (f[j + 1] - f[j]))
                if tr > c.start_s:
                    upd.update(end_s=tr, end_from=(f"the plate's acceleration falls below the ball's free "
                                                   f"acceleration {free_accel_mps2:.3f} m/s^2"))
        out.append(replace(c, **upd) if upd else c)
    return out
