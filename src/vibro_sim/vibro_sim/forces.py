"""Force laws acting on the ball during free flight (N, positive up).

Each law has ``force_n(v_mps, flight_index) -> float`` where ``v_mps`` is the ball's
velocity in the lab frame (m/s, positive up) and ``flight_index`` counts the free
flights from 0 (flight i ends with impact i). The ball's equation of motion is
m y'' = -m g cos(tilt) + F(v)   (paper Eq. 4 with F_friction = F).

``kind`` tells the COR model which exact solution to use: ``"constant"`` (piecewise
constant per flight: a parabola), ``"coulomb"`` (constant magnitude, sign flips at the
apex), ``"viscous"`` and ``"quadratic"`` (closed forms); anything else is integrated
numerically.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

from vibro_model.kinematics import StructureKinematics


def _finite(name: str, value: float, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if nonneg and value < 0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return float(value)


class ForceLaw:
    """Base class: subclasses define ``kind`` and ``force_n``."""

    kind = "ode"
    effect = "none"

    def force_n(self, v_mps: float, flight_index: int) -> float:  # pragma: no cover - interface
        raise NotImplementedError

    def parameters(self) -> dict:
        """Contract parameter names -> values (SI)."""
        return {}


@dataclass(frozen=True)
class NoForce(ForceLaw):
    """Gravity only (the baseline model)."""

    kind = "constant"
    effect = "none"

    def force_n(self, v_mps: float = 0.0, flight_index: int = 0) -> float:
        return 0.0

    def constant_n(self, flight_index: int) -> float:
        return 0.0


class Coulomb(ForceLaw):
    """Constant magnitude ``force_n`` (N, >= 0) opposing the ball's velocity; 0 at v = 0.

    The velocity is the ball's lab-frame velocity (contract: "opposing the ball's
    velocity"); during a flight the force flips sign at the apex.
    """

    kind = "coulomb"
    effect = "coulomb_friction"

    def __init__(self, force_n: float):
        self.magnitude_n = _finite("Coulomb.force_n", force_n, nonneg=True)

    def __repr__(self) -> str:
        return f"Coulomb({self.magnitude_n!r})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Coulomb) and other.magnitude_n == self.magnitude_n

    def __hash__(self) -> int:
        return hash(("Coulomb", self.magnitude_n))

    def force_n(self, v_mps: float, flight_index: int = 0) -> float:
        if v_mps > 0:
            return -self.magnitude_n
        if v_mps < 0:
            return self.magnitude_n
        return 0.0

    def parameters(self) -> dict:
        return {"force_n": self.magnitude_n}


@dataclass(frozen=True)
class Viscous(ForceLaw):
    """F = -c v with c = ``coefficient_ns_per_m`` (N s/m, >= 0)."""

    coefficient_ns_per_m: float

    kind = "viscous"
    effect = "viscous_drag"

    def __post_init__(self) -> None:
        _finite("Viscous.coefficient_ns_per_m", self.coefficient_ns_per_m, nonneg=True)

    def force_n(self, v_mps: float, flight_index: int = 0) -> float:
        return -self.coefficient_ns_per_m * v_mps

    def parameters(self) -> dict:
        return {"coefficient_ns_per_m": self.coefficient_ns_per_m}


@dataclass(frozen=True)
class Quadratic(ForceLaw):
    """F = -k v |v| with k = ``coefficient_ns2_per_m2`` (N s^2/m^2, >= 0)."""

    coefficient_ns2_per_m2: float

    kind = "quadratic"
    effect = "quadratic_drag"

    def __post_init__(self) -> None:
        _finite("Quadratic.coefficient_ns2_per_m2", self.coefficient_ns2_per_m2, nonneg=True)

    def force_n(self, v_mps: float, flight_index: int = 0) -> float:
        return -self.coefficient_ns2_per_m2 * v_mps * abs(v_mps)

    def parameters(self) -> dict:
        return {"coefficient_ns2_per_m2": self.coefficient_ns2_per_m2}


@dataclass(frozen=True)
class PerFlight(ForceLaw):
    """A constant force per flight (the paper's identified friction, Eq. 17, sign as identified).

    ``forces_n[i]`` (N, positive up) acts during flight i; flights past the end of the
    list use ``default_n``.
    """

    forces_n: Sequence[float] = field(default_factory=tuple)
    default_n: float = 0.0

    kind = "constant"
    effect = "per_flight_friction"

    def __post_init__(self) -> None:
        values = tuple(_finite(f"PerFlight.forces_n[{i}]", f) for i, f in enumerate(self.forces_n))
        object.__setattr__(self, "forces_n", values)
        _finite("PerFlight.default_n", self.default_n)

    def constant_n(self, flight_index: int) -> float:
        if 0 <= flight_index < len(self.forces_n):
            return self.forces_n[flight_index]
        return self.default_n

    def force_n(self, v_mps: float = 0.0, flight_index: int = 0) -> float:
        return self.constant_n(flight_index)


class PositionForce(ForceLaw):
    """A force towards the lower plate that decays with the ball's distance from it, on top of a velocity force
    law ``base`` (N, positive up) (the synthetic rig's out-of-catalogue ``position_force``,
    :mod:`vibro_sim.synth.invented`, and the discrepancy analysis' model of a located one):
    F(t, y, v) = base(v) - weight_fraction m g exp(-(y - Y_s(t) + b) / decay), integrated numerically by
    the COR model (kind "state"). ``force_n(v)`` (used only to decide when a ball riding a plate lifts
    off) is the force in contact with the lower plate."""

    kind = "state"
    effect = "position_force"

    def __init__(self, structure: StructureKinematics, free_play_m: float, mass_kg: float, g_mps2: float,
                 weight_fraction: float, decay_mm: float, base: ForceLaw | None = None):
        self.S, self.b = structure, float(free_play_m)
        self.peak_n = float(weight_fraction) * float(mass_kg) * float(g_mps2)
        self.decay_m = 1e-3 * float(decay_mm)
        self.weight_fraction, self.decay_mm = float(weight_fraction), float(decay_mm)
        self.base = base if base is not None else NoForce()

    def __repr__(self) -> str:
        return (f"PositionForce(weight_fraction={self.weight_fraction!r}, decay_mm={self.decay_mm!r}, "
                f"base={self.base!r})")

    def attraction_n(self, t_s: float, y_m: float) -> float:
        d = max(float(y_m) - float(self.S.position(t_s)) + self.b, 0.0)
        return -self.peak_n * math.exp(-d / self.decay_m)

    def force_state_n(self, t_s: float, y_m: float, v_mps: float) -> float:
        return self.base.force_n(v_mps, 0) + self.attraction_n(t_s, y_m)

    def force_n(self, v_mps: float, flight_index: int = 0) -> float:
        return self.base.force_n(v_mps, flight_index) - self.peak_n

    def parameters(self) -> dict:
        return {"weight_fraction": self.weight_fraction, "decay_mm": self.decay_mm}
