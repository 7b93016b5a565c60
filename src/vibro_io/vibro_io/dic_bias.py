"""DIC's sub-pixel bias (the S-curve) as results.json's ``dic_bias`` section states it, and the track with it taken
out (issue 39).

The identification measures the bias (:mod:`vibro_fit.subpixel_bias`: b(d) = sum_m a_m sin(2 pi m d) + b_m
cos(2 pi m d), d = displacement / camera.mm_per_px) and, where it is told from noise, identifies the recording on
the track with b(d) taken out. Every stage after it reads the track the same way: ``vibro analyze`` from its
identification, the graph's nodes and ``vibro results`` from the section the trajectory fitter publishes
(StructureMotion.dic_bias_json) via :func:`track_as_identified`, so every path measures the same track.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Mapping

import numpy as np

from vibro_model.codec import json_number as _num
from vibro_model.errors import RecordingError

from .dictrack import DicTrack


def bias_columns(displacement_mm: np.ndarray, mm_per_px: float, orders: int) -> np.ndarray:
    """[sin(2 pi m d), cos(2 pi m d)] for m = 1..orders, d = displacement_mm / mm_per_px (rows: frames)."""
    phase = 2.0 * np.pi * np.asarray(displacement_mm, dtype=float) / float(mm_per_px)
    return np.column_stack([f(m * phase) for m in range(1, orders + 1) for f in (np.sin, np.cos)])


@dataclass(frozen=True)
class BodyBias:
    """The S-curve of one body: ``coefficients_mm`` (a_1, b_1, a_2, b_2, ...: sin, cos of 2 pi m d, mm) with their
    standard errors, ``amplitude_px`` (of the first order, sqrt(a_1^2 + b_1^2) / mm_per_px) and its standard error,
    ``applied`` (taken out of the track) and why or why not (``reason``), the residual rms (mm) of the motion
    model without and with it, and the frames and the sweep (px) it was fitted on."""

    body: str
    coefficients_mm: tuple[float, ...] = ()
    coefficient_std_mm: tuple[float, ...] = ()
    amplitude_px: float = math.nan
    amplitude_std_px: float = math.nan
    applied: bool = False
    reason: str = ""
    rms_before_mm: float = math.nan
    rms_after_mm: float = math.nan
    frames: int = 0
    sweep_px: float = 0.0

    def bias_mm(self, displacement_mm: np.ndarray, mm_per_px: float) -> np.ndarray:
        """b(d) (mm) at the displacements ``displacement_mm`` (0 where not applied or not finite)."""
        d = np.asarray(displacement_mm, dtype=float)
        if not self.applied or not self.coefficients_mm:
            return np.zeros_like(d)
        cols = bias_columns(np.nan_to_num(d), mm_per_px, len(self.coefficients_mm) // 2)
        return np.where(np.isfinite(d), cols @ np.asarray(self.coefficients_mm, dtype=float), 0.0)

    def to_dict(self) -> dict:
        return {"applied": self.applied, "reason": self.reason, "amplitude_px": _num(self.amplitude_px),
                "amplitude_std_px": _num(self.amplitude_std_px),
                "coefficients_mm": [_num(c) for c in self.coefficients_mm],
                "coefficient_std_mm": [_num(c) for c in self.coefficient_std_mm],
                "rms_residual_before_mm": _num(self.rms_before_mm), "rms_residual_after_mm": _num(self.rms_after_mm),
                "frames": int(self.frames), "sweep_px": _num(self.sweep_px)}

    @classmethod
    def from_dict(cls, body: str, d: Mapping) -> "BodyBias":
        """From results.json's ``dic_bias.<body>`` (ValueError on a malformed one)."""
        coefs = tuple(float(c) for c in d.get("coefficients_mm") or ())
        if len(coefs) % 2 or not all(math.isfinite(c) for c in coefs):
            raise ValueError(f"dic_bias.{body}.coefficients_mm: expected pairs of finite numbers, got {coefs}")
        applied = d.get("applied")
        if not isinstance(applied, bool):
            raise ValueError(f"dic_bias.{body}.applied: expected true or false, got {applied!r}")
        if applied and not coefs:
            raise ValueError(f"dic_bias.{body}: applied without coefficients")
        return cls(body=body, coefficients_mm=coefs,
                   coefficient_std_mm=tuple(float(c) for c in d.get("coefficient_std_mm") or ()),
                   amplitude_px=_float(d.get("amplitude_px")), amplitude_std_px=_float(d.get("amplitude_std_px")),
                   applied=applied, reason=str(d.get("reason", "")),
                   rms_before_mm=_float(d.get("rms_residual_before_mm")),
                   rms_after_mm=_float(d.get("rms_residual_after_mm")), frames=int(d.get("frames") or 0),
                   sweep_px=_float(d.get("sweep_px")))


@dataclass(frozen=True)
class SubpixelBias:
    """Both bodies' S-curves and the image scale they are in (mm per px)."""

    mm_per_px: float
    structure: BodyBias = field(default_factory=lambda: BodyBias("structure"))
    ball: BodyBias = field(default_factory=lambda: BodyBias("ball"))

    @property
    def applied(self) -> bool:
        return self.structure.applied or self.ball.applied

    def corrected(self, track: DicTrack) -> DicTrack:
        """``track`` with each applied body's b(d) taken out of its displacements (the same frames, NaN kept)."""
        if not self.applied:
            return track
        return replace(track, ball_mm=track.ball_mm - self.ball.bias_mm(track.ball_mm, self.mm_per_px),
                       structure_mm=track.structure_mm - self.structure.bias_mm(track.structure_mm, self.mm_per_px))

    def to_dict(self) -> dict:
        """results.json's ``dic_bias`` section."""
        return {"model": "b(d) = sum_m a_m sin(2 pi m d) + b_m cos(2 pi m d), d = displacement_mm / mm_per_px; "
                         "coefficients_mm = [a_1, b_1, a_2, b_2]",
                "mm_per_px": _num(self.mm_per_px), "structure": self.structure.to_dict(), "ball": self.ball.to_dict()}

    @classmethod
    def from_dict(cls, d: Mapping) -> "SubpixelBias":
        """From results.json's ``dic_bias`` section (ValueError on a malformed one)."""
        scale = _float(d.get("mm_per_px"))
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"dic_bias.mm_per_px: expected a positive number, got {d.get('mm_per_px')!r}")
        return cls(mm_per_px=scale, structure=BodyBias.from_dict("structure", d.get("structure") or {}),
                   ball=BodyBias.from_dict("ball", d.get("ball") or {}))


def _float(x) -> float:
    try:
        return float(x) if x is not None else math.nan
    except (TypeError, ValueError):
        return math.nan


def bias_of_section(section: Any) -> SubpixelBias | None:
    """The :class:`SubpixelBias` of results.json's ``dic_bias`` ``section`` (None when None: an identification
    or a bag from before the section existed); RecordingError naming what is wrong in a damaged one."""
    if section is None:
        return None
    if not isinstance(section, Mapping):
        raise RecordingError(f"results dic_bias: expected a mapping, got {type(section).__name__}")
    try:
        return SubpixelBias.from_dict(section)
    except ValueError as exc:
        raise RecordingError(f"results {exc}") from None


def track_as_identified(track: DicTrack, section: Any) -> DicTrack:
    """``track`` (as tracked) with the sub-pixel bias results.json's ``dic_bias`` ``section`` took out (unchanged
    without one: :func:`bias_of_section`)."""
    bias = bias_of_section(section)
    return track if bias is None else bias.corrected(track)


def ball_as_identified(ball_mm: np.ndarray, section: Any) -> np.ndarray:
    """The ball's displacements (mm, as tracked) with the section's sub-pixel bias taken out (the simulator's
    measured ball, :func:`track_as_identified` for one column)."""
    bias = bias_of_section(section)
    ball = np.asarray(ball_mm, dtype=float)
    return ball if bias is None else ball - bias.ball.bias_mm(ball, bias.mm_per_px)
