"""Is there enough texture to track? Per-subset gradient energy against the image noise, before tracking.

Real balls are often not speckled: a dark sphere with a specular highlight, filmed on lossy video. DIC
measures a subset's displacement from its intensity gradients; with too little gradient against the noise,
the number it returns is noise. The DIC literature's criterion (Pan et al. 2008, "Study on subset size
selection in digital image correlation for speckle patterns", Opt. Express 16:7037) is the **sum of
squared subset intensity gradients** (SSSIG) along each axis,

    SSSIG_x = sum over the subset of (dI/dx)^2   (gray^2; same 4th-order central differences as the IC-GN)

and the displacement's standard deviation per axis, sigma_u ~ sqrt(2) sigma_noise / sqrt(SSSIG)
(:func:`vibro_dic.noise.cramer_rao_px`; sqrt(2): the reference and the current frame both carry noise).

The measured gradients of a noisy image hold the noise's own gradients: for white noise of std s their
squares add n_px * GRAD_NOISE_GAIN * s^2 in expectation (GRAD_NOISE_GAIN = sum of the squared
derivative taps = 130/144). That part is not texture (the noise does not move with the body): it is
subtracted, and the prediction uses ``sssig_signal = sssig - n_px * GRAD_NOISE_GAIN * s^2`` (a subset of
pure noise has sssig_signal ~ 0 and an infinite predicted sigma, not a small one).

The noise is estimated from the data (:func:`noise_from_frames`): the difference of two frames in the
blocks of the image that did not change between them (a static background, a fixed part of the rig). A
subset is **usable** when its predicted sigma (the worse axis) is at most ``max_subset_sigma_px``;
a body whose usable subsets are fewer than the tracker needs (``min_valid_fraction`` of its mesh) is
refused (:class:`TextureError`), with the numbers.

The predicted sigma of a body's displacement (the mean over its kept subsets, which overlap) is the
linearised estimator's exact propagation of white noise: each subset i estimates
u_i = sum_j g_j dn_j / H_i (g the gradient, H_i = SSSIG_i, dn the noise difference of the two frames), so
the mean over N subsets weighs pixel j by g_j A_j / N with A_j = sum over the subsets holding j of 1 / H_i,
and var = 2 s^2 / N^2 sum_j g_j^2 A_j^2 (:func:`mesh_sigma_px`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vibro_io.rig import DicConfig, Roi
from vibro_model.errors import RecordingError

from .icgn import gradients
from .mesh import mesh_points
from .noise import cramer_rao_px

GRAD_NOISE_GAIN = 130.0 / 144.0  # sum of the squared taps of the 4th-order central difference [1,-8,0,8,-1]/12
DEFAULT_MAX_SUBSET_SIGMA_PX = 0.05
NOISE_BLOCK_PX = 16
_STATIC_QUANTILE = 0.05  # the quietest blocks of the frame difference define "static"
_STATIC_FACTOR = 1.3     # blocks up to this factor above it are pooled (a 16x16 block's std scatters ~4.4 %)


class TextureError(RecordingError):
    """A body's ROI has too few subsets with enough texture against the noise (see the module doc)."""


@dataclass(frozen=True)
class NoiseEstimate:
    """Image noise std ``sigma_gray`` (gray levels) and how it was measured."""

    sigma_gray: float
    method: str
    n_pixels: int

    def describe(self) -> str:
        return f"{self.sigma_gray:.3g} gray levels ({self.method}, {self.n_pixels} px)"


def _clipped_value(image: np.ndarray) -> tuple[float, float]:
    if np.issubdtype(image.dtype, np.integer):
        info = np.iinfo(image.dtype)
        return float(info.min), float(info.max)
    return -math.inf, math.inf


def noise_from_frames(a: np.ndarray, b: np.ndarray, block_px: int = NOISE_BLOCK_PX) -> NoiseEstimate:
    """Noise std (gray levels) of one frame from the difference of two frames ``a``, ``b`` (same shape).

    The difference is cut into ``block_px`` square blocks; blocks touching a clipped pixel (0 or the
    dtype's maximum in either frame) are dropped (a saturated highlight has no noise to see). A block's
    mean is removed (illumination flicker), its std / sqrt(2) is that block's noise. Blocks that changed
    (motion) are louder: the estimate pools the blocks up to 1.3 x the 5 % quantile of the block values,
    i.e. the static part of the scene. Assumes noise that does not depend on the gray level; with none
    static (every block moves) it over-estimates the noise (a conservative check).
    """
    if a.shape != b.shape or a.ndim != 2:
        raise RecordingError(f"noise estimate: frames of shapes {a.shape} and {b.shape} (need two equal 2-D)")
    lo, hi = _clipped_value(a)
    rows, cols = (a.shape[0] // block_px) * block_px, (a.shape[1] // block_px) * block_px
    if rows == 0 or cols == 0:
        raise RecordingError(f"noise estimate: image {a.shape[1]}x{a.shape[0]} px smaller than one "
                             f"{block_px} px block")
    fa, fb = a[:rows, :cols].astype(np.float64), b[:rows, :cols].astype(np.float64)

    def blocks(x: np.ndarray) -> np.ndarray:
        return x.reshape(rows // block_px, block_px, cols // block_px, block_px).swapaxes(1, 2).reshape(
            -1, block_px * block_px)

    d = blocks(fb - fa)
    clipped = blocks((fa <= lo) | (fa >= hi) | (fb <= lo) | (fb >= hi)).any(axis=1)
    d = d[~clipped]
    if len(d) == 0:
        raise RecordingError("noise estimate: every block of the frame holds a clipped (saturated or black) pixel")
    var = d.var(axis=1, ddof=1)
    q = float(np.quantile(var, _STATIC_QUANTILE))
    quiet = var <= _STATIC_FACTOR ** 2 * q
    sigma = math.sqrt(float(var[quiet].mean()) / 2.0)
    return NoiseEstimate(sigma, f"difference of two frames, {int(quiet.sum())} static {block_px} px blocks",
                         int(quiet.sum()) * block_px * block_px)


def noise_from_image(image: np.ndarray) -> NoiseEstimate:
    """Noise std (gray levels) from one image: robust std (1.4826 MAD) of the Laplacian-difference
    high-pass [[1,-2,1],[-2,4,-2],[1,-2,1]] (Immerkaer 1996) divided by 6 (its white-noise gain). Texture
    adds to the high-pass: an upper bound for a speckled image. Used when only one frame exists."""
    x = image.astype(np.float64)
    hp = (x[:-2, :-2] - 2 * x[:-2, 1:-1] + x[:-2, 2:] - 2 * x[1:-1, :-2] + 4 * x[1:-1, 1:-1] - 2 * x[1:-1, 2:]
          + x[2:, :-2] - 2 * x[2:, 1:-1] + x[2:, 2:])
    med = np.median(hp)
    sigma = 1.4826 * float(np.median(np.abs(hp - med))) / 6.0
    return NoiseEstimate(sigma, "high-pass MAD of one frame", int(hp.size))


@dataclass
class BodyTexture:
    """Texture of one body's mesh in the reference frame (pixels, x = column, y = row down)."""

    name: str
    roi: Roi
    subset_px: int
    points: np.ndarray          # (N, 2) subset centres (x, y) px
    sssig: np.ndarray           # (N, 2) sum of squared gradients along x and y (gray^2), as measured
    sssig_noise: float          # its expected share from the noise alone (gray^2, each axis)
    sigma_px: np.ndarray        # (N, 2) predicted displacement std per axis (px); inf when no signal
    usable: np.ndarray          # (N,) bool: worse axis <= max_subset_sigma_px
    min_usable: int             # how many the tracker needs
    max_subset_sigma_px: float
    mesh_sigma_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))  # (2,) of the usable mean
    variance: np.ndarray = field(default_factory=lambda: np.empty(0))  # (N,) gray-level variance of each subset

    @property
    def sssig_signal(self) -> np.ndarray:
        return np.maximum(self.sssig - self.sssig_noise, 0.0)

    @property
    def n_usable(self) -> int:
        return int(np.count_nonzero(self.usable))

    @property
    def refused(self) -> bool:
        return self.n_usable < self.min_usable

    def _listing(self, idx: np.ndarray, limit: int = 6) -> str:
        parts = []
        for i in idx[:limit]:
            a = int(np.argmax(self.sigma_px[i]))  # the worse axis
            parts.append(f"({self.points[i, 0]:.0f}, {self.points[i, 1]:.0f}): SSSIG_{'xy'[a]} "
                         f"{self.sssig[i, a]:.3g} gray^2 ({self.sssig_signal[i, a]:.3g} above the noise), "
                         f"sigma {_fmt_px(self.sigma_px[i, a])}")
        more = f", and {len(idx) - limit} more" if len(idx) > limit else ""
        return "; ".join(parts) + more

    def problem(self, noise: NoiseEstimate) -> str | None:
        """One line naming the subsets above the threshold (None when every subset is usable)."""
        bad = np.flatnonzero(~self.usable)
        if bad.size == 0:
            return None
        head = (f"dic.{self.name}_roi {self.roi.as_list()}: {bad.size} of {len(self.points)} subsets "
                f"({self.subset_px} px) have too little texture against the image noise of {noise.describe()}: "
                f"predicted displacement sigma > {self.max_subset_sigma_px:g} px, i.e. SSSIG (sum of squared "
                f"gradients) < {self.min_sssig(noise.sigma_gray):.3g} gray^2 above the noise's own share of "
                f"{self.sssig_noise:.3g} gray^2 (worse axis; subset centre x, y px): ")
        tail = (f" -> {self.n_usable} usable, the tracker needs {self.min_usable}"
                + ("" if not self.refused else ": speckle the ball (or the structure), light it without "
                   "specular highlights, or use a larger subset (docs/real-footage.md)"))
        return head + self._listing(bad) + tail

    def min_sssig(self, noise_sigma: float) -> float:
        """SSSIG (gray^2, signal part) that gives exactly ``max_subset_sigma_px``."""
        return 2.0 * noise_sigma ** 2 / self.max_subset_sigma_px ** 2

    def to_dict(self) -> dict:
        sig = np.where(np.isfinite(self.sigma_px), self.sigma_px, None)
        return {
            "roi": self.roi.as_list(), "subset_px": self.subset_px, "n_subsets": len(self.points),
            "n_usable": self.n_usable, "min_usable": self.min_usable,
            "sssig_noise_gray2": float(self.sssig_noise),
            "mesh_sigma_px": [None if not math.isfinite(v) else float(v) for v in self.mesh_sigma_px],
            "subsets": [{"x_px": float(p[0]), "y_px": float(p[1]),
                         "sssig_x_gray2": float(s[0]), "sssig_y_gray2": float(s[1]),
                         "sigma_x_px": None if g[0] is None else float(g[0]),
                         "sigma_y_px": None if g[1] is None else float(g[1]), "usable": bool(u)}
                        for p, s, g, u in zip(self.points, self.sssig, sig, self.usable)],
        }


def _fmt_px(v: float) -> str:
    return "inf (no signal)" if not math.isfinite(v) else f"{v:.3g} px"


@dataclass
class TextureReport:
    """The texture check of both bodies against one noise estimate."""

    noise: NoiseEstimate
    bodies: dict[str, BodyTexture]

    def warnings(self) -> list[str]:
        """One line per body with subsets above the threshold (refused or not)."""
        return [m for m in (b.problem(self.noise) for b in self.bodies.values()) if m]

    def check(self) -> list[str]:
        """Raise :class:`TextureError` naming every body that has too few usable subsets; else the warnings."""
        refused = [b.problem(self.noise) for b in self.bodies.values() if b.refused]
        if refused:
            raise TextureError("texture check refused the tracking: " + " | ".join(refused))
        return self.warnings()

    def to_dict(self) -> dict:
        b0 = next(iter(self.bodies.values()), None)
        return {"noise_gray": self.noise.sigma_gray, "noise_method": self.noise.method,
                "max_subset_sigma_px": None if b0 is None else b0.max_subset_sigma_px,
                "bodies": {k: b.to_dict() for k, b in self.bodies.items()}}


def mesh_sigma_px(grad_xy: tuple[np.ndarray, np.ndarray], corners: np.ndarray, subset_px: int,
                  sssig: np.ndarray, noise_sigma: float) -> np.ndarray:
    """(2,) predicted std (px) along x and y of the mean of the subsets' displacements (module doc):
    ``corners`` (N, 2) top-left pixels of the subsets, ``sssig`` (N, 2) their SSSIG (gray^2)."""
    n = len(corners)
    if n == 0:
        return np.full(2, np.nan)
    x0, y0 = corners.min(axis=0).astype(int)
    x1, y1 = corners.max(axis=0).astype(int) + subset_px
    out = np.empty(2)
    for axis in range(2):
        a = np.zeros((y1 - y0, x1 - x0))
        for (cx, cy), h in zip(corners.astype(int), sssig[:, axis]):
            a[cy - y0:cy - y0 + subset_px, cx - x0:cx - x0 + subset_px] += 1.0 / h if h > 0 else np.inf
        g = grad_xy[axis][y0:y1, x0:x1].astype(np.float64)
        with np.errstate(invalid="ignore"):
            out[axis] = math.sqrt(2.0) * noise_sigma / n * math.sqrt(float(np.nansum((g * a) ** 2)))
    return out


def assess_body(name: str, reference: np.ndarray, roi: Roi, subset_px: int, step_px: int, noise: NoiseEstimate,
                *, max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX, min_valid_fraction: float = 0.5,
                grad_xy: tuple[np.ndarray, np.ndarray] | None = None) -> BodyTexture:
    """Texture of the mesh of ``roi`` in ``reference`` (2-D, gray levels) against ``noise``."""
    points = mesh_points(roi, subset_px, step_px)
    n = len(points)
    gx, gy = grad_xy if grad_xy is not None else gradients(reference)
    corners = (points - subset_px // 2).astype(int)
    sssig = np.empty((n, 2))
    ref = np.asarray(reference, dtype=np.float64)
    variance = np.array([ref[cy:cy + subset_px, cx:cx + subset_px].var() for cx, cy in corners])
    for axis, g in enumerate((gx, gy)):
        g2 = g.astype(np.float64) ** 2
        for i, (cx, cy) in enumerate(corners):
            sssig[i, axis] = g2[cy:cy + subset_px, cx:cx + subset_px].sum()
    s = noise.sigma_gray
    sssig_noise = subset_px * subset_px * GRAD_NOISE_GAIN * s * s
    signal = np.maximum(sssig - sssig_noise, 0.0)
    with np.errstate(divide="ignore"):
        sigma = np.where(signal > 0, cramer_rao_px(np.where(signal > 0, signal, 1.0), s), np.inf)
    usable = sigma.max(axis=1) <= max_subset_sigma_px
    body = BodyTexture(name, roi, subset_px, points, sssig, sssig_noise, sigma, usable,
                       max(1, math.ceil(min_valid_fraction * n - 1e-9)), max_subset_sigma_px, variance=variance)
    if usable.any():
        body.mesh_sigma_px = mesh_sigma_px((gx, gy), corners[usable], subset_px, sssig[usable], s)
    return body


def assess_texture(reference: np.ndarray, dic: DicConfig, noise: NoiseEstimate, *,
                   max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX,
                   min_valid_fraction: float = 0.5) -> TextureReport:
    """Texture of the ball's and the structure's meshes (rig.yaml ``dic``) in the reference frame."""
    if not (math.isfinite(max_subset_sigma_px) and max_subset_sigma_px > 0):
        raise RecordingError(f"max_subset_sigma_px must be a positive number (px), got {max_subset_sigma_px!r}")
    grad = gradients(np.asarray(reference))
    bodies = {name: assess_body(name, reference, getattr(dic, f"{name}_roi"), dic.subset_px, dic.mesh_step_px,
                                noise, max_subset_sigma_px=max_subset_sigma_px,
                                min_valid_fraction=min_valid_fraction, grad_xy=grad)
              for name in ("ball", "structure")}
    return TextureReport(noise, bodies)


def check_texture(reference: np.ndarray, second: np.ndarray | None, dic: DicConfig, *,
                  max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX,
                  min_valid_fraction: float = 0.5) -> tuple[TextureReport, list[str]]:
    """The texture check before tracking (the CLI's and the node's): noise from ``reference`` and ``second``
    (another frame; None or the same pixels: the one-frame estimate), then :func:`assess_texture`.
    Returns (report, warnings); raises :class:`TextureError` when a body has too few usable subsets."""
    ref = np.asarray(reference)
    if second is not None and second.shape == ref.shape and not np.array_equal(second, ref):
        noise = noise_from_frames(ref, second)
    else:
        noise = noise_from_image(ref)
    report = assess_texture(ref, dic, noise, max_subset_sigma_px=max_subset_sigma_px,
                            min_valid_fraction=min_valid_fraction)
    return report, report.check()
