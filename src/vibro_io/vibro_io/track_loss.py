"""A body lost in most frames of a track: the one refusal rule and message of every path.

``vibro analyze`` refuses a track whose ball or structure was lost in more than half of the frames
(:class:`vibro_dic.quality.TrackQuality`, from the tracker's own results); the graph's trajectory fitter and
``vibro results`` of a bag see only the DIC track (dic.csv, the DicFrames: a lost body's displacement is NaN)
and refuse it through the cross-checks (:func:`vibro_fit.cross_checks.consistency_checks`). Both build their
words here, so every path refuses the same track with the same message and exit code. A ball that had turned
:data:`SPIN_HINT_DEG` or more since frame 0 when it was first lost spins: the message says so and names the
remedy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: a body lost in more than this fraction of the frames is refused
MAX_LOST_FRACTION = 0.5
#: (deg) a body that had turned this far since frame 0 when it was first lost: a spin, not a texture problem
SPIN_HINT_DEG = 3.0
#: how many of the first lost frames a message names
FIRST_NAMED = 5
#: the rig.yaml keys of each body's tracking
BODY_KEYS = {"ball": ["dic.ball_roi", "dic.ball_method"], "structure": ["dic.structure_roi"]}


@dataclass(frozen=True)
class BodyLoss:
    """How often one body was lost: ``lost`` of ``frames``, the first lost frame indices, and its rotation since
    frame 0 (deg) in the last tracked frame before its first loss (None: not measured)."""

    name: str
    frames: int
    lost: int
    first_lost: tuple[int, ...] = ()
    rotation_at_first_loss_deg: float | None = None

    def refused(self, max_lost_fraction: float = MAX_LOST_FRACTION) -> bool:
        """Lost in more than ``max_lost_fraction`` of its frames."""
        return self.frames > 0 and self.lost > max_lost_fraction * self.frames


def track_losses(track) -> list[BodyLoss]:
    """Each body's losses in a :class:`vibro_io.dictrack.DicTrack` (a body is lost where its displacement is not
    finite); the ball's rotation at its first loss from ``ball_rot_rad``."""
    out = []
    frames = np.asarray(track.frame)
    for name, column in (("ball", track.ball_mm), ("structure", track.structure_mm)):
        lost = ~np.isfinite(np.asarray(column, dtype=float))
        where = np.flatnonzero(lost)
        rot = None
        if name == "ball" and where.size:
            before = np.asarray(track.ball_rot_rad, dtype=float)[:where[0]]
            finite = before[np.isfinite(before)]
            rot = math.degrees(float(finite[-1])) if finite.size else None
        out.append(BodyLoss(name, int(lost.size), int(where.size), tuple(int(k) for k in frames[where[:FIRST_NAMED]]),
                            rot))
    return out


def lost_refusal(losses: list[BodyLoss], max_lost_fraction: float = MAX_LOST_FRACTION) -> str | None:
    """The refusal message for the bodies lost in more than ``max_lost_fraction`` of the frames, or None."""
    bad = [b for b in losses if b.refused(max_lost_fraction)]
    if not bad:
        return None
    parts = [f"{b.name} lost in {b.lost} of {b.frames} frames ({b.lost / b.frames:.0%} > {max_lost_fraction:.0%}; "
             f"first: {', '.join(map(str, b.first_lost))})" for b in bad]
    return ("tracking refused: " + "; ".join(parts) + ": check the ROIs, the texture and the lighting "
            "(docs/real-footage.md)" + spin_hint(bad))


def spin_hint(losses: list[BodyLoss]) -> str:
    """Where a lost body had turned :data:`SPIN_HINT_DEG` or more when first lost: why, and the remedy."""
    turned = [b for b in losses if b.rotation_at_first_loss_deg is not None
              and abs(b.rotation_at_first_loss_deg) >= SPIN_HINT_DEG]
    if not turned:
        return ""
    words = ", ".join(f"the {b.name} had turned {b.rotation_at_first_loss_deg:+.1f} deg since frame 0" for b in turned)
    return (f"; {words} when it was first lost: it spins, and its subsets (translations against frame 0) lose "
            "the speckle within a few degrees; track it by its outline instead (rig.yaml dic.ball_method: outline, "
            "dic.ball_roi a box around the whole ball on a plain background)")
