"""Frame-by-frame identification with one flight of latency (the core of the trajectory_fitter node).

``StreamingFitter.push(frame)`` returns the impact estimates that became available with this frame:
an impact is emitted as soon as the flight after it is closed (the next contact cluster starts) and
fitted. :func:`vibro_fit.identify.identify` runs exactly this class over the whole track, so both paths
give the same per-impact results.

Structure velocity at an impact comes from a *local* sine fit over the good structure samples in
[t_start(flight before) - history_s, t_end(flight after)] (history_s = one nominal period by default),
which is known when the impact is emitted and is robust to slow drifts of a real shaker.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from vibro_io.dictrack import FrameTrack
from vibro_model.constants import G_MPS2

from .flight_fit import FlightFit, fit_flight
from .gaps import GapEvidence, GapVerdict, gap_impact
from .impacts import ImpactFit, joint_impact, paper_impact
from .segmentation import SegmentationConfig, accel_estimate, noise_sigma_mm
from .structure_fit import fit_structure


@dataclass
class Cluster:
    """A run of contact frames (track frame indices)."""

    frames: list[int]
    t_start_s: float
    t_end_s: float

    @property
    def n(self) -> int:
        return len(self.frames)


def _shifted(fl: FlightFit, lo: int) -> FlightFit:
    """A shallow copy of ``fl`` whose frame indices are relative to ``lo``."""
    from dataclasses import replace

    return replace(fl, frames=fl.frames - lo)


@dataclass(frozen=True, kw_only=True)
class StreamingTuning:
    """Windows of :class:`StreamingFitter`: ``warmup_frames``, the frames the noise is estimated from when it
    is not given; ``history_s`` (s), how far before the flight before an impact the structure's local sine is
    fitted (None: one nominal period)."""

    warmup_frames: int = 100
    history_s: float | None = None


class StreamingFitter:
    """Incremental segmentation, flight fits and impact estimates.

    Parameters: ``frequency_hz`` nominal excitation (Hz); ``noise_mm`` ball position noise (mm) or None
    to estimate it from the first ``warmup_frames`` frames; ``method`` "paper" or "joint" (joint uses the
    running median relative position of each plate over the impacts so far, from 3 impacts on);
    ``weights`` None or "dic_valid": weight each frame of a flight fit by its number of valid ball mesh
    points (the DIC displacement is their mean, so its variance goes as 1 / valid); ``tuning``: the warm-up
    and structure-history windows (:class:`StreamingTuning`).
    """

    def __init__(self, frequency_hz: float, *, noise_mm: float | None = None, method: str = "paper",
                 config: SegmentationConfig | None = None, tuning: StreamingTuning | None = None,
                 weights: str | None = None, free_play_mm: float | None = None,
                 contact_frames: set[int] | None = None) -> None:
        if method not in ("paper", "joint"):
            raise ValueError(f"unknown method {method!r} (paper, joint)")
        if weights not in (None, "none", "dic_valid"):
            raise ValueError(f"unknown weights {weights!r} (none, dic_valid)")
        self.weights = None if weights == "none" else weights
        self.frequency_hz = float(frequency_hz)
        self.cfg = config or SegmentationConfig()
        self.method = method
        self.noise_mm = noise_mm
        tuning = tuning or StreamingTuning()
        self.warmup_frames = tuning.warmup_frames
        self.history_s = tuning.history_s if tuning.history_s is not None else 1.0 / self.frequency_hz
        self.t: list[float] = []
        self.ball: list[float] = []
        self.struct: list[float] = []
        self.valid: list[float] = []
        self.good_frames: list[int] = []     # track indices of good frames
        self.flags: list[bool] = []          # per good position
        self.ext_times: list[float] = []     # accelerometer impact times (camera clock, s)
        self.flights: list[FlightFit] = []
        self.impacts: list[ImpactFit] = []
        self.clusters: list[Cluster] = []
        self.short_flights: list[FlightFit] = []
        self.rejected: list[str] = []
        self._cluster_start: int | None = None   # good position
        self._flight_start: int | None = 0       # good position of the open flight
        self._prev_cluster: Cluster | None = None  # last cluster, if no flight closed since
        self._last_flight: FlightFit | None = None
        self._flight_queue: list[FlightFit] = []
        self._n_flight = 0
        self._n_impact = 0
        self._finished = False
        self._short_gap = 0                      # lost frames inside the impact gap being closed
        self.gaps: list[GapVerdict] = []         # runs of lost frames longer than an impact's contact frames
        self.free_play_mm = free_play_mm
        # track indices known to be contact (the ball riding a plate, vibro_fit.contacts): contact frames
        # whatever their acceleration
        self.contact_frames = set(contact_frames or ())

    # ------------------------------------------------------------------ input
    def push_accel_impact(self, t_s: float) -> None:
        """An impact instant from the accelerometers, already on the camera clock (s). It must arrive
        before the frame after it is pushed to take effect."""
        self.ext_times.append(float(t_s))
        self.ext_times.sort()

    def push(self, frame: FrameTrack) -> list[ImpactFit]:
        """Add one frame (in order); returns the impacts estimated because of it (usually none)."""
        idx = len(self.t)
        self.t.append(float(frame.t_s))
        self.ball.append(float(frame.ball_mm))
        self.struct.append(float(frame.structure_mm))
        self.valid.append(float(max(frame.ball_valid, 0)))
        good = (not frame.lost) and math.isfinite(frame.ball_mm) and math.isfinite(frame.structure_mm)
        if good:
            self.good_frames.append(idx)
        if self.noise_mm is None:
            if len(self.t) < self.warmup_frames:
                return []
            self.noise_mm = noise_sigma_mm(np.array(self.t), np.array(self.ball), self.cfg.g_mps2)
            if not np.isfinite(self.noise_mm):
                self.noise_mm = 0.0
        return self._advance()

    def finish(self) -> list[ImpactFit]:
        """End of data: close the open flight. Returns impacts emitted by that."""
        if self._finished:
            return []
        if self.noise_mm is None:
            self.noise_mm = noise_sigma_mm(np.array(self.t), np.array(self.ball), self.cfg.g_mps2) if self.t else 0.0
            if not np.isfinite(self.noise_mm):
                self.noise_mm = 0.0
        out = self._advance()
        self._finished = True
        n = len(self.good_frames)
        # the last good position has no flag (no right neighbour): treat as non-contact
        while len(self.flags) < n:
            self.flags.append(False)
        if self._cluster_start is not None:
            self._close_cluster(n - 2)
        elif self._flight_start is not None and self._flight_start < n:
            out += self._close_flight(self._flight_start, n - 1)
        return out

    def pop_flights(self) -> list[FlightFit]:
        """Fitted flights closed since the last call (for a flight message). A flight merged across a
        spurious contact cluster is sent again with the same index (the new one replaces the old)."""
        out, self._flight_queue = self._flight_queue, []
        return out

    def structure_estimate(self, window_s: float | None = None):
        """Sine fit (StructureFit) of the structure over the last ``window_s`` (default: everything so
        far), or None with fewer than 8 good samples."""
        g = np.asarray(self.good_frames, int)
        if g.size < 8:
            return None
        t = np.asarray(self.t)[g]
        s = np.asarray(self.struct)[g]
        if window_s is not None:
            keep = t >= t[-1] - window_s
            t, s = t[keep], s[keep]
            if t.size < 8:
                return None
        return fit_structure(t, s, f0_hz=self.frequency_hz)

    # ------------------------------------------------------------------ core
    def _is_contact(self, pos: int) -> bool:
        g = self.good_frames
        t = self.t
        if pos <= 0 or pos >= len(g) - 1:
            return False
        i, j, k = g[pos - 1], g[pos], g[pos + 1]
        if j in self.contact_frames:
            return True
        acc, fac = accel_estimate(np.array([t[i], t[j], t[k]]), np.array([self.ball[i], self.ball[j], self.ball[k]]))
        thr = max(self.cfg.k_sigma * fac * float(self.noise_mm), self.cfg.min_threshold_mps2)
        if abs(acc + self.cfg.g_mps2) > thr:
            return True
        if self.ext_times:
            # an accelerometer impact in (t_i, t_k]: this frame is next to it
            m = bisect.bisect_right(self.ext_times, t[i])
            if m < len(self.ext_times) and self.ext_times[m] <= t[k]:
                return True
        return False

    def _advance(self) -> list[ImpactFit]:
        out: list[ImpactFit] = []
        n = len(self.good_frames)
        # a flag needs the right neighbour: positions 0..n-2 can be evaluated
        while len(self.flags) < n - 1:
            pos = len(self.flags)
            flag = self._is_contact(pos)
            self.flags.append(flag)
            if flag and self._cluster_start is None:
                # a contact cluster starts: the flight before it is complete -> fit it now
                self._cluster_start = pos
                if self._flight_start is not None and pos - 1 >= self._flight_start:
                    out += self._close_flight(self._flight_start, pos - 1)
                self._flight_start = None
            elif not flag and self._cluster_start is not None:
                self._close_cluster(pos - 1)
                self._flight_start = pos
        return out

    def _close_cluster(self, end_pos: int) -> None:
        g = self.good_frames
        frames = [g[p] for p in range(self._cluster_start, end_pos + 1)]
        cl = Cluster(frames, self.t[frames[0]], self.t[frames[-1]])
        self._cluster_start = None
        if self._prev_cluster is not None and self.clusters and self.clusters[-1] is self._prev_cluster:
            # no flight since the previous cluster: one longer contact phase
            cl = Cluster(self._prev_cluster.frames + frames, self._prev_cluster.t_start_s, cl.t_end_s)
            self.clusters[-1] = cl
        else:
            self.clusters.append(cl)
        self._prev_cluster = cl

    def _close_flight(self, p0: int, p1: int) -> list[ImpactFit]:
        g = self.good_frames
        frames = np.array([g[p] for p in range(p0, p1 + 1)], int)
        fl = self._fit(self._n_flight, frames)
        cluster_before = self._prev_cluster
        self._prev_cluster = None
        out: list[ImpactFit] = []
        if not fl.fitted:
            self.short_flights.append(fl)
            self._last_flight = None
            return out
        self._check_free(fl)
        prev = self._last_flight
        lost = self._lost_between(prev, fl) if prev is not None else 0
        if prev is not None and lost > 0 and \
                int(fl.frames[0]) - int(prev.frames[-1]) - 1 > self.cfg.max_impact_frames:
            # frames without DIC between the two flights, more than one impact's contact frames: the ball
            # may have struck several times unseen. One impact is reported only where the flights, the
            # plate and the energy determine it (vibro_fit.gaps); else the gap and what it may hide are said
            est = self._gap_impact(prev, fl, lost) if prev.is_free and fl.is_free else None
            if est is not None:
                self.impacts.append(est)
                out.append(est)
                self._n_impact += 1
            elif not (prev.is_free and fl.is_free):
                self.rejected.append(
                    f"no impact between flights {prev.index} and {fl.index} (t {prev.t_end_s:.4f}..{fl.t_start_s:.4f} "
                    f"s): {lost} frames in between have no DIC result; impacts there are not identified")
            prev = None
        elif prev is not None and lost > 0:
            self._short_gap = lost
        if (prev is not None and prev.is_free and fl.is_free and cluster_before is not None
                and cluster_before.n <= self.cfg.max_impact_frames):
            est = self._impact(prev, fl)
            if est is None:
                merged = self._try_merge(prev, fl)
                if merged is not None:
                    self._last_flight = merged
                    return out
                self.rejected.append(
                    f"no impact between flights {prev.index} and {fl.index} "
                    f"(t {prev.t_end_s:.4f}..{fl.t_start_s:.4f} s): parabolas do not meet in the gap")
            else:
                if self._short_gap:   # found by the plain path, but inside lost frames: said so
                    est.in_gap, est.gap_lost_frames = True, self._short_gap
                self.impacts.append(est)
                out.append(est)
                self._n_impact += 1
        self._short_gap = 0
        self.flights.append(fl)
        self._flight_queue.append(fl)
        self._n_flight += 1
        self._last_flight = fl
        return out

    def _lost_between(self, p: FlightFit, q: FlightFit) -> int:
        """Frames between the end of flight ``p`` and the start of ``q`` that are lost (no usable DIC)."""
        lo, hi = int(p.frames[-1]), int(q.frames[0])
        usable = bisect.bisect_left(self.good_frames, hi) - bisect.bisect_right(self.good_frames, lo)
        return (hi - lo - 1) - usable

    def _fit(self, index: int, frames: np.ndarray) -> FlightFit:
        """Fit a flight on global frame indices, building arrays over its span only (bounded cost)."""
        lo, hi = int(frames[0]), int(frames[-1]) + 1
        t = np.asarray(self.t[lo:hi])
        y = np.asarray(self.ball[lo:hi])
        w = None
        if self.weights == "dic_valid":
            w = np.asarray(self.valid[lo:hi], float)
            pos = w[frames - lo]
            w = w / max(float(np.median(pos[pos > 0])) if np.any(pos > 0) else 1.0, 1e-12)
        fl = fit_flight(index, frames - lo, t, y, self.cfg.min_points, w)
        fl.frames = frames
        return fl

    def _check_free(self, fl: FlightFit) -> None:
        c = self.cfg
        limit = c.rms_factor * float(self.noise_mm or 0.0) + c.rms_floor_mm
        if fl.rms_residual_mm > limit:
            fl.is_free = False
            fl.reason = f"residual {fl.rms_residual_mm:.4f} mm > {limit:.4f} mm: not a parabola (contact?)"
        elif abs(fl.acceleration_mps2 + c.g_mps2) > c.max_friction_g * G_MPS2:
            # the bound is a force, a fraction of the ball's weight m g, whatever the axis' orientation: on a
            # horizontal axis (g_mps2 = 0) a free flight is a straight line plus the guide rods' friction
            fl.is_free = False
            fl.reason = (f"acceleration {fl.acceleration_mps2:.2f} m/s^2 too far from the axis' gravity "
                         f"-{c.g_mps2:.2f} m/s^2: not a free flight")

    def _structure_window(self, p: FlightFit, q: FlightFit):
        # good frames with t in [t_start(p) - history_s, t_end(q)], found backwards from the end
        g = self.good_frames
        t0 = p.t_start_s - self.history_s
        sel = []
        for idx in reversed(g):
            ti = self.t[idx]
            if ti < t0:
                break
            if ti <= q.t_end_s:
                sel.append(idx)
        sel.reverse()
        return fit_structure(np.array([self.t[i] for i in sel]), np.array([self.struct[i] for i in sel]),
                             f0_hz=self.frequency_hz)

    def _gap_impact(self, p: FlightFit, q: FlightFit, lost: int) -> ImpactFit | None:
        """The impact inside the lost frames between ``p`` and ``q`` when determined (:mod:`.gaps`); the
        verdict is kept in :attr:`gaps`, an undetermined one also as a rejection (warning)."""
        s_fit = self._structure_window(p, q)
        lo = bisect.bisect_right(self.ext_times, p.t_end_s)
        hi = bisect.bisect_left(self.ext_times, q.t_start_s)
        dt = float(np.median(np.diff(self.t[-50:]))) if len(self.t) > 2 else 0.0
        evidence = GapEvidence(prior=self.impacts, accel_times_s=self.ext_times[lo:hi], frame_dt_s=dt,
                               free_play_mm=self.free_play_mm)
        est, verdict = gap_impact(self._n_impact, p, q, s_fit, lost, evidence)
        self.gaps.append(verdict)
        if est is None:
            self.rejected.append(verdict.warning())
            return None
        self._set_directions(p, q, est)
        return est

    def _impact(self, p: FlightFit, q: FlightFit) -> ImpactFit | None:
        s_fit = self._structure_window(p, q)
        est = paper_impact(self._n_impact, p, q, s_fit)
        if est is None:
            return None
        self._set_directions(p, q, est)
        if self.method == "joint":
            prior = [i.y_rel_mm for i in self.impacts if i.plate == est.plate]
            if len(prior) >= 3:
                lo, hi = int(p.frames[0]), int(q.frames[-1]) + 1
                pl = _shifted(p, lo)
                ql = _shifted(q, lo)
                est = joint_impact(est, pl, ql, np.asarray(self.t[lo:hi]), np.asarray(self.ball[lo:hi]),
                                   float(np.median(prior[-50:])))
        return est

    @staticmethod
    def _set_directions(p: FlightFit, q: FlightFit, est: ImpactFit) -> None:
        if not p.direction:
            p.direction = "up" if est.plate == "top" else "down"
        q.direction = "down" if est.plate == "top" else "up"

    def _try_merge(self, p: FlightFit, q: FlightFit) -> FlightFit | None:
        frames = np.concatenate([p.frames, q.frames])
        fl = self._fit(p.index, frames)
        self._check_free(fl)
        if not fl.is_free:
            return None
        fl.direction = p.direction
        fl.notes.append(f"merged across a spurious contact cluster at {p.t_end_s:.4f}..{q.t_start_s:.4f} s")
        self.flights[-1] = fl
        self._flight_queue.append(fl)
        return fl
