"""Coefficient-of-restitution laws (paper Eq. 5).

Each law has ``cor(plate, v_rel_mps, impact_index) -> e`` with ``plate`` ``"top"`` or
``"bottom"``, ``v_rel_mps`` the ball's velocity relative to the structure just before
the impact (m/s, signed, positive up) and ``impact_index`` counting impacts from 0.
After the impact: v_b+ - v_s = -e (v_b- - v_s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

PLATES = ("top", "bottom")


def _cor_value(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    return float(value)


def _check_plate(plate: str) -> None:
    if plate not in PLATES:
        raise ValueError(f"plate must be 'top' or 'bottom', got {plate!r}")


class RestitutionLaw:
    """Base class of COR laws."""

    effect = "none"

    def cor(self, plate: str, v_rel_mps: float, impact_index: int) -> float:  # pragma: no cover
        raise NotImplementedError

    def parameters(self) -> dict:
        return {}


@dataclass(frozen=True)
class Constant(RestitutionLaw):
    """The same e for every impact (the baseline model)."""

    e: float

    def __post_init__(self) -> None:
        _cor_value("Constant.e", self.e)

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        _check_plate(plate)
        return self.e


@dataclass(frozen=True)
class PerPlate(RestitutionLaw):
    """e = ``top`` on the upper plate, ``bottom`` on the lower plate."""

    top: float
    bottom: float

    effect = "asymmetric_restitution"

    def __post_init__(self) -> None:
        _cor_value("PerPlate.top", self.top)
        _cor_value("PerPlate.bottom", self.bottom)

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        _check_plate(plate)
        return self.top if plate == "top" else self.bottom

    def parameters(self) -> dict:
        return {"cor_top": self.top, "cor_bottom": self.bottom}


@dataclass(frozen=True)
class VelocityDependent(RestitutionLaw):
    """e = cor_at_zero - slope * |v_rel|, clipped to [0, 1]."""

    cor_at_zero: float
    slope_s_per_m: float

    effect = "velocity_dependent_restitution"

    def __post_init__(self) -> None:
        _cor_value("VelocityDependent.cor_at_zero", self.cor_at_zero)
        if not math.isfinite(self.slope_s_per_m):
            raise ValueError(f"VelocityDependent.slope_s_per_m must be finite, got {self.slope_s_per_m!r}")

    def cor(self, plate: str, v_rel_mps: float, impact_index: int = 0) -> float:
        _check_plate(plate)
        return float(min(1.0, max(0.0, self.cor_at_zero - self.slope_s_per_m * abs(v_rel_mps))))

    def parameters(self) -> dict:
        return {"cor_at_zero": self.cor_at_zero, "slope_s_per_m": self.slope_s_per_m}


@dataclass(frozen=True)
class PerImpact(RestitutionLaw):
    """e = ``cors[impact_index]`` (the paper's identified CORs, in impact order).

    Impacts past the end of the list use ``default`` (None: the mean of the list).
    """

    cors: Sequence[float] = field(default_factory=tuple)
    default: float | None = None

    def __post_init__(self) -> None:
        values = tuple(_cor_value(f"PerImpact.cors[{i}]", e) for i, e in enumerate(self.cors))
        object.__setattr__(self, "cors", values)
        if self.default is None:
            if not values:
                raise ValueError("PerImpact needs at least one COR or a default")
            object.__setattr__(self, "default", float(np.mean(values)))
        else:
            _cor_value("PerImpact.default", self.default)

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        _check_plate(plate)
        if 0 <= impact_index < len(self.cors):
            return self.cors[impact_index]
        return float(self.default)


@dataclass(frozen=True)
class Scattered(RestitutionLaw):
    """Wraps a law and adds Gaussian scatter: e_i = base(...) + sigma z_i, clipped to [0, 1].

    z_i is a fixed standard-normal sequence drawn from ``seed``, so impact i always gets
    the same draw (repeatable simulations).
    """

    base: RestitutionLaw
    sigma: float
    seed: int = 0
    max_impacts: int = 100_000

    def __post_init__(self) -> None:
        if not math.isfinite(self.sigma) or self.sigma < 0:
            raise ValueError(f"Scattered.sigma must be >= 0, got {self.sigma!r}")
        rng = np.random.default_rng(self.seed)
        object.__setattr__(self, "_z", rng.standard_normal(self.max_impacts))

    @property
    def effect(self) -> str:  # type: ignore[override]
        return self.base.effect

    def cor(self, plate: str, v_rel_mps: float = 0.0, impact_index: int = 0) -> float:
        e = self.base.cor(plate, v_rel_mps, impact_index)
        z = self._z[impact_index % self.max_impacts]  # type: ignore[attr-defined]
        return float(min(1.0, max(0.0, e + self.sigma * z)))

    def parameters(self) -> dict:
        return dict(self.base.parameters(), cor_sigma=self.sigma)
