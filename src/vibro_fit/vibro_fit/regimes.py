"""Classify the motion regime of the ball from the segmentation.

Rules (per recording; counts are per excitation cycle, n_cycles = duration x frequency):
- ``resting``: contact phases (clusters longer than an impact) cover more than half the record, or no
  impact at all (neither with a COR nor a landing without one) while the ball moves with the structure
  (ball - structure range < 10 % of 2b).
- ``chatter_with_sticking``: the ball rides a plate (contact phases found from the positions,
  :mod:`vibro_fit.contacts`) after hops on it, in at least every other cycle, covering at most half the
  record (rarer contact phases are noted under the other names); ``description`` names the
  plate ("chatter with sticking on the lower plate"), the hops per cycle and the time on the plate. The
  model has no term for riding: the regime is described, never turned into a physics finding.
- ``chattering``: more than 0.3 short flights (too few frames to fit) or same-plate re-impacts within a
  quarter period per cycle.
- ``two_impacts_per_cycle``: top and bottom impacts each 0.8..1.2 per cycle.
- ``one_impact_per_cycle``: 0.8..1.2 impacts per cycle in total.
- ``no_impacts`` / ``irregular`` otherwise.
Only impacts between two free flights carry a COR (enforced by the streaming fitter).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(kw_only=True)
class Regime:
    name: str
    n_cycles: float
    top_per_cycle: float
    bottom_per_cycle: float
    short_flights: int
    contact_fraction: float
    notes: list[str] = field(default_factory=list)
    description: str = ""

    def to_dict(self) -> dict:
        out = {"name": self.name, "n_cycles": self.n_cycles, "top_per_cycle": self.top_per_cycle,
               "bottom_per_cycle": self.bottom_per_cycle, "short_flights": self.short_flights,
               "contact_fraction": self.contact_fraction, "notes": list(self.notes)}
        if self.description:
            out["description"] = self.description
        return out


@dataclass(frozen=True, kw_only=True)
class RegimeEvidence:
    """What the regime is classified from: the record's duration (s), the excitation frequency (Hz), the COR
    impacts, contact clusters and short flights of the segmentation, the most frames of an impact's cluster,
    the frame interval (s), the range of ball - structure (mm), the free play (mm); ``n_landings``: impacts
    without a COR (:mod:`vibro_fit.landings`), noted and never called resting; ``contacts``: the ball riding a
    plate (:class:`vibro_fit.contacts.ContactPhase`); ``n_hop_impacts``: the impacts between short hops among
    ``impacts`` (:mod:`vibro_fit.hops`)."""

    duration_s: float
    frequency_hz: float
    impacts: list
    clusters: list
    short_flights: list
    max_impact_frames: int
    frame_dt_s: float
    y_rel_range_mm: float
    free_play_mm: float
    n_landings: int = 0
    contacts: tuple | list = ()
    n_hop_impacts: int = 0


def classify_regime(ev: RegimeEvidence) -> Regime:
    """Regime from the impacts, contact clusters and short flights of a recording (see module rules)."""
    duration_s, frequency_hz, impacts, clusters = ev.duration_s, ev.frequency_hz, ev.impacts, ev.clusters
    short_flights, max_impact_frames, frame_dt_s = ev.short_flights, ev.max_impact_frames, ev.frame_dt_s
    y_rel_range_mm, free_play_mm, n_landings = ev.y_rel_range_mm, ev.free_play_mm, ev.n_landings
    n_cycles = max(duration_s * frequency_hz, 1e-9)
    contacts = list(ev.contacts)
    if contacts and len(contacts) >= 0.5 * n_cycles:
        return _sticking(ev, n_cycles, contacts)
    n_top = sum(1 for i in impacts if i.plate == "top")
    n_bot = sum(1 for i in impacts if i.plate == "bottom")
    contact_s = sum((c.n + 1) * frame_dt_s for c in clusters if c.n > max_impact_frames)
    contact_fraction = contact_s / max(duration_s, 1e-12)
    quarter = 0.25 / frequency_hz
    rebounds = 0
    for a, b in zip(impacts[:-1], impacts[1:]):
        if a.plate == b.plate and b.t_s - a.t_s < quarter:
            rebounds += 1
    chatter = (len(short_flights) + rebounds) / n_cycles
    notes: list[str] = []
    top_pc, bot_pc = n_top / n_cycles, n_bot / n_cycles
    if contact_fraction > 0.5:
        name = "resting"
        notes.append(f"ball in contact with a plate {100 * contact_fraction:.0f} % of the time")
    elif not impacts and not n_landings and y_rel_range_mm < 0.2 * free_play_mm:
        name = "resting"
        notes.append(f"no impact and the ball moves with the structure (relative range {y_rel_range_mm:.3f} mm, "
                     f"free play b = {free_play_mm:.3f} mm)")
    elif chatter > 0.3:
        name = "chattering"
        notes.append(f"{len(short_flights)} short flights and {rebounds} quick same-plate re-impacts")
    elif 0.8 <= top_pc <= 1.2 and 0.8 <= bot_pc <= 1.2:
        name = "two_impacts_per_cycle"
    elif 0.8 <= top_pc + bot_pc <= 1.2:
        name = "one_impact_per_cycle"
    elif not impacts:
        name = "no_impacts"
    else:
        name = "irregular"
    n_phases = sum(1 for c in clusters if c.n > max_impact_frames)
    if n_landings:
        notes.append(f"{n_landings} impact(s) without a COR (rebound too short to fit, or chatter/sticking after it)")
    if n_phases and name != "resting":
        notes.append(f"{n_phases} contact phase(s) (chatter or sticking, {100 * contact_fraction:.0f} % of the time)")
    return Regime(name=name, n_cycles=float(n_cycles), top_per_cycle=float(top_pc), bottom_per_cycle=float(bot_pc),
                  short_flights=len(short_flights),
                  contact_fraction=float(contact_fraction), notes=notes)


def _sticking(ev: RegimeEvidence, n_cycles: float, contacts: list) -> Regime:
    """``chatter_with_sticking`` (or ``resting`` beyond half the record on a plate) from the contact phases."""
    duration_s, impacts, short_flights, frame_dt_s = ev.duration_s, ev.impacts, ev.short_flights, ev.frame_dt_s
    n_landings, n_hop_impacts = ev.n_landings, ev.n_hop_impacts
    n_top = sum(1 for i in impacts if i.plate == "top")
    n_bot = sum(1 for i in impacts if i.plate == "bottom")
    on = {p: sum(c.end_s - c.start_s + frame_dt_s for c in contacts if c.plate == p) for p in ("top", "bottom")}
    frac = sum(on.values()) / max(duration_s, 1e-12)
    plate = max(on, key=on.get)
    word = "lower" if plate == "bottom" else "upper"
    n_ph = sum(1 for c in contacts if c.plate == plate)
    notes = [f"{len(contacts)} contact phase(s): the ball rides the {word} plate {100 * frac:.0f} % of the time "
             f"(mean {1e3 * on[plate] / max(n_ph, 1):.1f} ms each)"]
    if n_hop_impacts:
        notes.append(f"{n_hop_impacts} impact(s) between short hops measured on the plate (hop chains)")
    if n_landings:
        notes.append(f"{n_landings} impact(s) without a COR (the last hops, too short to fit)")
    if frac > 0.5:
        name = "resting"
        desc = f"resting on the {word} plate {100 * frac:.0f} % of the time"
    else:
        name = "chatter_with_sticking"
        hops = (n_top if plate == "top" else n_bot) / max(n_ph, 1)
        desc = (f"chatter with sticking on the {word} plate: per contact phase {hops:.1f} impact(s) with a COR "
                f"(landing and hops), then the ball rides the plate ({100 * frac:.0f} % of the time) until its "
                "acceleration releases it; the model has no term for riding, so this is described, not a finding")
    return Regime(name=name, n_cycles=float(n_cycles), top_per_cycle=float(n_top / n_cycles),
                  bottom_per_cycle=float(n_bot / n_cycles), short_flights=len(short_flights),
                  contact_fraction=float(frac), notes=notes, description=desc)


def y_rel_range(ball_mm: np.ndarray, structure_mm: np.ndarray) -> float:
    """Range (mm) of ball - structure over the finite samples (robust: 1st..99th percentile)."""
    r = np.asarray(ball_mm) - np.asarray(structure_mm)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return 0.0
    lo, hi = np.percentile(r, [1, 99])
    return float(hi - lo)
