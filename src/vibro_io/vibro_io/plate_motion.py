"""Each plate's motion against the tracked structure as results.json's ``plate_motion`` section states it.

The identification (:mod:`vibro_fit.plate_motion`) measures each plate's height against the tracked structure
from its contact levels and, where a plate creeps, takes the creep's velocity into the CORs of the impacts on it.
The discrepancy analysis re-measures impacts under its models (:mod:`vibro_discrepancy.reidentify`); it reads
the same plate velocity from the section (:func:`plate_creeps`), from ``vibro analyze``'s identification or from
the trajectory fitter's StructureMotion.plate_motion_json, so every path measures the same CORs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from vibro_model.errors import RecordingError

PLATES = ("top", "bottom")


def creep_velocity_mps(coef_um: np.ndarray, t_ref_s: float, t_s: float) -> float:
    """The derivative at ``t_s`` (s) of the level polynomial ``coef_um`` (um against t - ``t_ref_s``, highest power
    first), in m/s."""
    coef = np.asarray(coef_um, dtype=float)
    if coef.size < 2:
        return 0.0
    return 1e-6 * float(np.polyval(np.polyder(coef), t_s - t_ref_s))


@dataclass(frozen=True)
class PlateCreep:
    """A plate that creeps against the tracked structure, taken into the CORs: its level polynomial (um against
    t - ``t_ref_s``, highest power first)."""

    plate: str
    coef_um: tuple[float, ...]
    t_ref_s: float

    def velocity_mps(self, t_s: float) -> float:
        """The plate's velocity against the tracked structure at ``t_s`` (m/s)."""
        return creep_velocity_mps(np.asarray(self.coef_um), self.t_ref_s, t_s)

    def level_um(self, t_s: float) -> float:
        """The plate's height against the tracked structure at ``t_s`` (um, about the polynomial's own zero)."""
        return float(np.polyval(np.asarray(self.coef_um), t_s - self.t_ref_s))


def plate_creeps(section: Any, where: str = "results.plate_motion") -> dict[str, PlateCreep]:
    """The plates whose creep the identification took into the CORs (``applied`` true), from a ``plate_motion``
    section; {} for None (a results file or bag written before the section existed). Raises RecordingError naming
    the key when the section is damaged where it changes a COR (``applied``, ``coef_um``, ``t_ref_s``)."""
    if section is None:
        return {}
    if not isinstance(section, Mapping):
        raise RecordingError(f"{where} must be an object, got {type(section).__name__}")
    out = {}
    for plate, entry in section.items():
        at = f"{where}.{plate}"
        if plate not in PLATES:
            raise RecordingError(f"{at}: unknown plate (top, bottom)")
        if not isinstance(entry, Mapping):
            raise RecordingError(f"{at} must be an object, got {type(entry).__name__}")
        applied = entry.get("applied")
        if not isinstance(applied, bool):
            raise RecordingError(f"{at}.applied must be true or false, got {applied!r}")
        if not applied:
            continue
        coef, t_ref = entry.get("coef_um"), entry.get("t_ref_s")
        if (not isinstance(coef, list) or not coef
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in coef)):
            raise RecordingError(f"{at}.coef_um must be a non-empty list of finite numbers, got {coef!r}")
        if not isinstance(t_ref, (int, float)) or isinstance(t_ref, bool) or not math.isfinite(t_ref):
            raise RecordingError(f"{at}.t_ref_s must be a finite number, got {t_ref!r}")
        out[plate] = PlateCreep(plate, tuple(float(c) for c in coef), float(t_ref))
    return out
