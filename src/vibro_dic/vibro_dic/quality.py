"""Correlation quality along a track: per body, how well each frame matched the reference.

Fed one frame at a time with the tracker's per-mesh results (:class:`vibro_dic.tracker.MeshResult`), it
keeps per body (constant memory per frame: one number and the subsets' kept counts):

- ``zncc_median``, ``zncc_min``: of the mesh's mean ZNCC (kept subsets) over the tracked frames;
- ``frames_below``: tracked frames whose mean ZNCC is below ``zncc_warn`` (default 0.9: a tenth of the
  subset's variance no longer explained by a shifted copy of the reference: the pattern changed:
  a highlight, blur, compression, a background crossing the ROI), with the first few frame indices;
- ``frames_lost``; ``subsets_lost``: subsets kept in fewer than half of the tracked frames;
- ``noise_from_zncc_gray``: the noise the correlation sees. For a subset of gray-level variance V
  (reference) matched to a copy with independent noise of std s in each image, 1 - ZNCC = s^2 / V, so
  s_eff = sqrt(median over frames of the mean over kept subsets of (1 - ZNCC_i) V_i). It holds the image
  noise plus everything else that differs between the frames (lossy compression, interpolation, changing
  appearance). Its ratio to the image noise of the texture check (:mod:`vibro_dic.texture`) scales that
  check's predicted displacement sigma into ``sigma_px_from_zncc`` (motion axis y), the error the track
  actually carries; a ratio above ``max_noise_ratio`` (2) is warned.

Refused (:class:`TrackQualityError`): a body lost in more than ``max_lost_fraction`` (0.5) of the frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vibro_io.track_loss import MAX_LOST_FRACTION, BodyLoss, lost_refusal
from vibro_model.errors import RecordingError

from .texture import TextureReport

DEFAULT_ZNCC_WARN = 0.9
DEFAULT_MAX_LOST_FRACTION = MAX_LOST_FRACTION   # the one rule of every path (vibro_io.track_loss)
DEFAULT_MAX_NOISE_RATIO = 2.0
_FIRST = 5  # frame indices listed in a message


class TrackQualityError(RecordingError):
    """A body was lost in too many frames to be analysed (numbers in the message)."""


@dataclass(kw_only=True)
class _Body:
    n_subsets: int
    frames: int = 0
    lost: int = 0
    zncc: list[float] = field(default_factory=list)
    residual_var: list[float] = field(default_factory=list)  # per tracked frame: mean (1 - zncc_i) V_i (gray^2)
    below: int = 0
    first_below: list[int] = field(default_factory=list)
    first_lost: list[int] = field(default_factory=list)
    kept: np.ndarray | None = None
    last_rot_rad: float | None = None          # the rotation (since frame 0) of the last tracked frame
    rot_at_first_loss_rad: float | None = None  # the rotation of the last tracked frame before the first loss


class TrackQuality:
    """Accumulates the correlation quality of a track (module doc). ``texture``: the texture check of the
    same reference (gives the subsets' variance, the image noise and the predicted sigma), or None."""

    def __init__(self, texture: TextureReport | None = None, *, zncc_warn: float = DEFAULT_ZNCC_WARN,
                 max_lost_fraction: float = DEFAULT_MAX_LOST_FRACTION,
                 max_noise_ratio: float = DEFAULT_MAX_NOISE_RATIO):
        if not 0.0 < zncc_warn < 1.0:
            raise RecordingError(f"zncc_warn must be in (0, 1), got {zncc_warn!r}")
        if not 0.0 < max_lost_fraction <= 1.0:
            raise RecordingError(f"max_lost_fraction must be in (0, 1], got {max_lost_fraction!r}")
        self.texture = texture
        #: how the ball was tracked (:class:`vibro_dic.ball_method.BallMethodChoice`), when known
        self.ball_method = None
        self.zncc_warn = zncc_warn
        self.max_lost_fraction = max_lost_fraction
        self.max_noise_ratio = max_noise_ratio
        self.bodies: dict[str, _Body] = {}

    def _body(self, name: str, n: int) -> _Body:
        if name not in self.bodies:
            self.bodies[name] = _Body(n_subsets=n, kept=np.zeros(n, dtype=np.int64))
        return self.bodies[name]

    def add(self, frame_index: int, results: dict) -> None:
        """One frame: ``results`` {body: MeshResult} (the tracker's ``last_results``; empty when the image
        was missing: every body known so far counts it lost)."""
        if not results:
            for b in self.bodies.values():
                b.frames += 1
                b.lost += 1
                if len(b.first_lost) < _FIRST:
                    b.first_lost.append(frame_index)
                if b.lost == 1:
                    b.rot_at_first_loss_rad = b.last_rot_rad
            return
        for name, r in results.items():
            n = len(r.point_valid) if len(r.point_valid) else (self.bodies[name].n_subsets if name in self.bodies
                                                                else 0)
            b = self._body(name, n)
            b.frames += 1
            if r.lost or not math.isfinite(r.zncc):
                b.lost += 1
                if len(b.first_lost) < _FIRST:
                    b.first_lost.append(frame_index)
                if b.lost == 1:
                    b.rot_at_first_loss_rad = b.last_rot_rad
                continue
            rot = getattr(r, "rot_rad", math.nan)
            if math.isfinite(rot):
                b.last_rot_rad = float(rot)
            b.zncc.append(float(r.zncc))
            if r.zncc < self.zncc_warn:
                b.below += 1
                if len(b.first_below) < _FIRST:
                    b.first_below.append(frame_index)
            if b.kept is not None and len(r.point_valid) == len(b.kept):
                b.kept += r.point_valid  # bool counts as 0/1
                var = self._variance(name)
                if var is not None and len(var) == len(b.kept) and r.valid > 0:
                    v = r.point_valid
                    # ZNCC <= 1 mathematically; a subset matching its reference to rounding (frame 0 itself) can
                    # read 1 + 1e-12: no residual, not a negative one (once per frame: plain ufuncs, not clip/mean)
                    residual = 1.0 - r.point_zncc[v]
                    np.maximum(residual, 0.0, out=residual)
                    b.residual_var.append(float(residual @ var[v]) / len(residual))

    def _variance(self, name: str) -> np.ndarray | None:
        if self.texture is None or name not in self.texture.bodies:
            return None
        return self.texture.bodies[name].variance

    def summary(self) -> dict:
        """{"zncc_warn", "max_lost_fraction", "noise_gray", "bodies": {name: {...}}} (plain JSON, see module doc)."""
        noise = self.texture.noise.sigma_gray if self.texture is not None else None
        out: dict = {"zncc_warn": self.zncc_warn, "max_lost_fraction": self.max_lost_fraction,
                     "max_noise_ratio": self.max_noise_ratio, "noise_gray": noise, "bodies": {}}
        for name, b in self.bodies.items():
            tracked = len(b.zncc)
            kept_frac = (b.kept / tracked).tolist() if tracked and b.kept is not None else []
            lost_subsets = [i for i, f in enumerate(kept_frac) if f < 0.5]
            s_eff = math.sqrt(float(np.median(b.residual_var))) if b.residual_var else None
            ratio = s_eff / noise if s_eff is not None and noise else None
            mesh_y = None
            if self.texture is not None and name in self.texture.bodies:
                m = float(self.texture.bodies[name].mesh_sigma_px[1])
                mesh_y = m if math.isfinite(m) else None
            out["bodies"][name] = {
                "frames": b.frames, "frames_tracked": tracked, "frames_lost": b.lost, "first_lost": b.first_lost,
                "zncc_median": float(np.median(b.zncc)) if tracked else None,
                "zncc_min": float(np.min(b.zncc)) if tracked else None,
                "frames_below_zncc_warn": b.below, "first_below": b.first_below,
                "n_subsets": b.n_subsets, "subset_kept_fraction": kept_frac, "subsets_lost": lost_subsets,
                "noise_from_zncc_gray": s_eff, "noise_ratio": ratio,
                "sigma_px_predicted": mesh_y,
                "sigma_px_from_zncc": None if mesh_y is None or ratio is None else mesh_y * max(ratio, 1.0),
                "rotation_at_first_loss_deg": (None if b.rot_at_first_loss_rad is None
                                               else math.degrees(b.rot_at_first_loss_rad)),
            }
        return out

    def warnings(self) -> list[str]:
        """One line per finding, with its numbers."""
        out = []
        s = self.summary()
        for name, b in s["bodies"].items():
            if b["frames_lost"]:
                out.append(f"{name}: lost in {b['frames_lost']} of {b['frames']} frames (first: "
                           f"{', '.join(map(str, b['first_lost']))})")
            if b["frames_below_zncc_warn"]:
                out.append(f"{name}: mean ZNCC below {self.zncc_warn:g} in {b['frames_below_zncc_warn']} of "
                           f"{b['frames_tracked']} tracked frames (first: {', '.join(map(str, b['first_below']))}; "
                           f"median {b['zncc_median']:.4f}, min {b['zncc_min']:.4f}): the pattern changes between "
                           "frames (highlight, blur, lossy compression, background in the ROI)")
            if b["subsets_lost"]:
                out.append(f"{name}: {len(b['subsets_lost'])} of {b['n_subsets']} subsets kept in fewer than half "
                           f"of the tracked frames (subset indices {b['subsets_lost'][:8]})")
            r = b["noise_ratio"]
            if r is not None and r > self.max_noise_ratio:
                out.append(f"{name}: the correlation sees {b['noise_from_zncc_gray']:.3g} gray levels of noise, "
                           f"{r:.1f} x the image noise of {s['noise_gray']:.3g} (median ZNCC {b['zncc_median']:.4f}): "
                           "the frames differ by more than noise (lossy compression, changing appearance); the "
                           f"displacement sigma is about {b['sigma_px_from_zncc']:.3g} px, not the "
                           f"{b['sigma_px_predicted']:.3g} px the texture predicts")
        return out

    def check(self) -> list[str]:
        """Raise :class:`TrackQualityError` for a body lost in more than ``max_lost_fraction`` of the frames;
        else return :meth:`warnings`."""
        losses = [BodyLoss(name, b["frames"], b["frames_lost"], tuple(b["first_lost"]), b["rotation_at_first_loss_deg"])
                  for name, b in self.summary()["bodies"].items()]
        refusal = lost_refusal(losses, self.max_lost_fraction)
        if refusal is not None:
            raise TrackQualityError(refusal)
        return self.warnings()


def dic_quality_section(texture: TextureReport | None, quality: TrackQuality | None) -> dict:
    """The results.json ``dic_quality`` section: the texture check and the correlation quality, and (when
    known) how the ball was tracked: ``ball_method``, ``ball_method_source`` ("rig.yaml" or "texture check")
    and ``ball_method_reason``."""
    out = {"texture": None if texture is None else texture.to_dict(),
           "correlation": None if quality is None else quality.summary()}
    if quality is not None and quality.ball_method is not None:
        out.update(quality.ball_method.to_dict())
    return out

