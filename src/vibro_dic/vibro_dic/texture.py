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

The noise is estimated from the data (:func:`estimate_noise`, in gray levels of the delivered pixels):

- **Frame difference** (:func:`noise_from_frames`): the difference of two frames in the blocks of the image
  that did not change between them (a static background, a fixed part of the rig). Blocks holding a
  clipped pixel are left out, clipping judged against the file's **effective depth** (:class:`PixelDepth`):
  an N-bit camera delivered in uint16 puts its codes at the top of 16 bits, so its brightest code is
  65535 - (2**(16 - N) - 1) (65520 for 12 bits), not the dtype's maximum.
- It is **not** used when the frames come from a lossy video codec (:func:`codec_is_lossy`: a codec copies
  unchanged blocks and smooths flat ones, so identical pixels are the codec's work, not a noiseless sensor),
  nor when it is **degenerate** (:func:`degenerate_reason`): below the quantization noise of the effective
  depth, or more than half of the static difference exactly 0. White noise of std s on a code grid of step c
  leaves a difference D of std sqrt(2) s, exactly 0 with probability P(|D| < c/2) = erf(c / (4 s)) > 1/2
  only for s < 0.52 c: at most half a code of noise, where the quantization floor rules anyway. So an
  honest sensor stays below that mark; a codec's copies do not.
- Then the **correlation** estimate (:func:`noise_from_correlation`), on the DIC's own subsets: each subset
  of frame a is matched in frame b (ZNCC search, then IC-GN with the tracker's 6-tap interpolant). For
  a = f + n_a and the matched b = f + n_b' (n_b' the noise of b interpolated at the sub-pixel match, of
  variance gamma s^2, gamma = the interpolant's white-noise gain, sum of its squared weights along x times
  along y: 1 at a whole-pixel shift, less in between) and V_f the subset's signal variance,

      ZNCC = V_f / sqrt((V_f + s^2)(V_f + gamma s^2)) = 1 - (1 + gamma) s^2 / (2 V_f) + O(s^4 / V_f^2),

  so s^2 = 2 (1 - ZNCC) V / (1 + gamma) with V the measured subset variance (exact at gamma = 1, where
  1 - ZNCC = s^2 / (V_f + s^2)). The median over the subsets is the estimate: the noise the correlation
  sees, image noise plus everything else that differs between the frames (a codec's errors). Subsets
  that frame b repeats pixel for pixel are left out (a copy is no evidence) unless the frames are
  known to be lossless; too few left refuses the check for a lossy video (:class:`TextureError`).
- Whatever the estimate, the noise is never below the **quantization noise** of the effective depth, one
  code / sqrt(12) (uniform rounding error over a code): 1/sqrt(12) gray level for 8-bit, 16/sqrt(12) for a
  12-bit camera delivered in uint16 (:func:`floor_noise`). A noise of 0 (float images have no code grid)
  would predict 0 px of DIC error, which is impossible: :func:`assess_texture` refuses it.

A subset is **usable** when its predicted sigma (the worse axis) is at most ``max_subset_sigma_px``;
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
from dataclasses import dataclass, field, replace

import numpy as np

from vibro_io.rig import DicConfig, Roi
from vibro_model.errors import RecordingError

from .icgn import IcgnBlocks, gradients
from .interp import kernel_weights, patch_margin
from .mesh import mesh_points
from .noise import cramer_rao_px
from .outline import assess_outline
from .search import zncc_search

GRAD_NOISE_GAIN = 130.0 / 144.0  # sum of the squared taps of the 4th-order central difference [1,-8,0,8,-1]/12
DEFAULT_MAX_SUBSET_SIGMA_PX = 0.05
NOISE_BLOCK_PX = 16
_STATIC_QUANTILE = 0.05  # the quietest blocks of the frame difference define "static"
_STATIC_FACTOR = 1.3     # blocks up to this factor above it are pooled (a 16x16 block's std scatters ~4.4 %)
MAX_ZERO_SHARE = 0.5     # more exact zeros in the static difference: degenerate (module doc)
CORRELATION_SUBSET_PX = 31   # subsets of the correlation estimate when no DIC mesh is given (px)
CORRELATION_SEARCH_PX = 8    # integer ZNCC search of each subset, +- px around its frame-a position
CORRELATION_ZNCC_MIN = 0.6   # a match below this is no match (the tracker's default zncc_min)
MIN_CORRELATION_SUBSETS = 4  # fewer matched subsets give no correlation estimate
#: a subset with more clipped pixels is left out of the correlation estimate: clipped pixels carry no noise, so a
#: share p of them lowers the estimated variance by p: 2 % biases sigma by 1 %, below the ~2 % scatter of one subset
MAX_CLIPPED_SHARE = 0.02
_INTERP_TAPS = 6             # the tracker's interpolant (vibro_dic.interp)
#: FourCCs of lossless video codecs, as :attr:`vibro_io.frames.FrameSequence.codec` gives them (NULs and
#: spaces stripped, compared in upper case): FFV1, HuffYUV (HFYU, FFmpeg's FFVH), uncompressed (""
#: for a zero FourCC, "DIB", "RAW", "Y800", "Y8", "GREY", "Y16"), PNG in AVI (MPNG). "" is also what image
#: folders and camera files give. Any other codec, known or not, counts as lossy.
LOSSLESS_CODECS = frozenset({"", "FFV1", "HFYU", "FFVH", "DIB", "RAW", "Y800", "Y8", "GREY", "Y16", "MPNG"})


class TextureError(RecordingError):
    """A body's ROI has too few subsets with enough texture against the noise (see the module doc)."""


@dataclass(frozen=True)
class NoiseEstimate:
    """Image noise std ``sigma_gray`` (gray levels of the delivered pixels) and how it was measured.

    ``n_pixels``: pixels it rests on; ``zero_share``: share of those whose frame difference is exactly 0
    (frame-difference estimate only; NaN otherwise).
    """

    sigma_gray: float
    method: str
    n_pixels: int
    zero_share: float = math.nan

    def describe(self) -> str:
        return f"{self.sigma_gray:.3g} gray levels ({self.method}, {self.n_pixels} px)"


# ------------------------------------------------------------------------------ pixel depth, clipping
@dataclass(frozen=True)
class PixelDepth:
    """The gray-level scale of delivered pixels: ``container_bits`` (8 for uint8, 16 for uint16; None for
    float images, which have no code grid) and ``effective_bits``, the significant bits, at the top of the
    container (an N-bit camera in uint16 delivers value << (16 - N))."""

    container_bits: int | None
    effective_bits: int | None

    @property
    def code_gray(self) -> float:
        """One code of the effective depth in delivered gray levels, 2**(container - effective); 0 for floats."""
        if self.container_bits is None or self.effective_bits is None:
            return 0.0
        return float(2 ** (self.container_bits - self.effective_bits))

    @property
    def quantization_sigma_gray(self) -> float:
        """Std of the rounding to one code (uniform over a code): code / sqrt(12) gray levels; 0 for floats."""
        return self.code_gray / math.sqrt(12.0)

    @property
    def black_gray(self) -> float:
        """The lowest code (gray levels): black-clipped at or below it."""
        return 0.0 if self.container_bits is not None else -math.inf

    @property
    def brightest_gray(self) -> float:
        """The brightest code (gray levels): saturated at or above it (65520 for 12 bits in uint16)."""
        if self.container_bits is None:
            return math.inf
        return float(2 ** self.container_bits) - self.code_gray

    def saturated(self, image: np.ndarray) -> np.ndarray:
        """Mask of the pixels at the brightest code of the effective depth (or above)."""
        return np.asarray(image) >= self.brightest_gray

    def clipped(self, image: np.ndarray) -> np.ndarray:
        """Mask of the saturated or black-clipped pixels: they carry no noise to measure."""
        img = np.asarray(image)
        return (img >= self.brightest_gray) | (img <= self.black_gray)

    def describe(self) -> str:
        if self.container_bits is None:
            return "float pixels"
        return f"{self.effective_bits}-bit pixels in {self.container_bits}-bit words"


def pixel_depth(image: np.ndarray, effective_bits: int | None = None) -> PixelDepth:
    """The :class:`PixelDepth` of ``image`` (uint8 or uint16; float: no code grid) with ``effective_bits``
    significant bits (:attr:`vibro_io.frames.FrameSequence.effective_bits`). None: 8 for uint8; for uint16
    the bits above the trailing zero bits every pixel shares (exact for MSB-aligned camera pixels, 16 when
    any pixel has its lowest bit set)."""
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):
        return PixelDepth(None, None)
    container = 8 * img.dtype.itemsize
    if effective_bits is None:
        effective_bits = container if container == 8 else _aligned_bits(img, container)
    if not 1 <= int(effective_bits) <= container:
        raise RecordingError(f"effective bit depth {effective_bits} does not fit {container}-bit pixels")
    return PixelDepth(container, int(effective_bits))


def _aligned_bits(image: np.ndarray, container: int) -> int:
    """Significant bits of MSB-aligned pixels: ``container`` less the trailing zero bits of every pixel."""
    ored = int(np.bitwise_or.reduce(image, axis=None))
    if ored == 0:
        return container
    return container - ((ored & -ored).bit_length() - 1)


def codec_is_lossy(codec: str | None) -> bool:
    """True for a video FourCC not in :data:`LOSSLESS_CODECS` (unknown codecs count as lossy). False for ""
    (image files, camera files, uncompressed video) and for None (frames of unknown origin, e.g. received
    over ROS: judged by :func:`degenerate_reason` alone)."""
    if codec is None:
        return False
    return codec.strip("\x00 ").upper() not in LOSSLESS_CODECS


# ------------------------------------------------------------------------------ frame-difference estimate
def _blocks(x: np.ndarray, block_px: int) -> np.ndarray:
    """(n_blocks, block_px**2) view of the ``block_px`` square blocks of ``x`` (cropped to whole blocks)."""
    rows, cols = x.shape
    return x.reshape(rows // block_px, block_px, cols // block_px, block_px).swapaxes(1, 2).reshape(
        -1, block_px * block_px)


def noise_from_frames(a: np.ndarray, b: np.ndarray, block_px: int = NOISE_BLOCK_PX, *,
                      effective_bits: int | None = None) -> NoiseEstimate:
    """Noise std (gray levels) of one frame from the difference of two frames ``a``, ``b`` (same shape).

    The difference is cut into ``block_px`` square blocks; blocks touching a clipped pixel in either frame
    (black, or saturated against the ``effective_bits`` depth: :func:`pixel_depth`) are dropped (a
    saturated highlight or backlight has no noise to see). A block's mean is removed (illumination
    flicker), its std / sqrt(2) is that block's noise. Blocks that changed (motion) are louder: the
    estimate pools the blocks up to 1.3 x the 5 % quantile of the block values, i.e. the static part of
    the scene. Assumes noise that does not depend on the gray level; with none static (every block moves)
    it over-estimates the noise (a conservative check). Not floored: see :func:`estimate_noise`.
    """
    if a.shape != b.shape or a.ndim != 2:
        raise RecordingError(f"noise estimate: frames of shapes {a.shape} and {b.shape} (need two equal 2-D)")
    depth = pixel_depth(a, effective_bits)
    rows, cols = (a.shape[0] // block_px) * block_px, (a.shape[1] // block_px) * block_px
    if rows == 0 or cols == 0:
        raise RecordingError(f"noise estimate: image {a.shape[1]}x{a.shape[0]} px smaller than one "
                             f"{block_px} px block")
    ra, rb = a[:rows, :cols], b[:rows, :cols]
    d = _blocks(rb.astype(np.float64) - ra.astype(np.float64), block_px)
    clipped = _blocks(depth.clipped(ra) | depth.clipped(rb), block_px).any(axis=1)
    d = d[~clipped]
    if len(d) == 0:
        raise RecordingError(f"noise estimate: every block of the frame holds a clipped pixel (black, or "
                             f"saturated at {depth.brightest_gray:g}: {depth.describe()})")
    var = d.var(axis=1, ddof=1)
    q = float(np.quantile(var, _STATIC_QUANTILE))
    quiet = var <= _STATIC_FACTOR ** 2 * q
    sigma = math.sqrt(float(var[quiet].mean()) / 2.0)
    n_quiet = int(quiet.sum())
    return NoiseEstimate(sigma, f"difference of two frames, {n_quiet} static {block_px} px blocks of "
                                f"{len(d) + int(clipped.sum())} ({int(clipped.sum())} with a clipped pixel left out)",
                         n_quiet * block_px * block_px, float(np.mean(d[quiet] == 0.0)))


def degenerate_reason(estimate: NoiseEstimate, depth: PixelDepth) -> str | None:
    """Why a frame-difference ``estimate`` is no evidence of the noise (module doc), or None when it is."""
    q = depth.quantization_sigma_gray
    if not estimate.sigma_gray >= q:
        return (f"the static-area estimate of {estimate.sigma_gray:.3g} gray levels is below the quantization noise "
                f"{q:.3g} of {depth.describe()}")
    if estimate.zero_share > MAX_ZERO_SHARE:
        return (f"{100 * estimate.zero_share:.1f} % of the static frame difference is exactly 0 (white noise "
                f"leaves more than {100 * MAX_ZERO_SHARE:.0f} % only below half a code)")
    return None


def noise_from_image(image: np.ndarray, *, effective_bits: int | None = None) -> NoiseEstimate:
    """Noise std (gray levels) from one image: robust std (1.4826 MAD) of the Laplacian-difference
    high-pass [[1,-2,1],[-2,4,-2],[1,-2,1]] (Immerkaer 1996) divided by 6 (its white-noise gain), over the
    pixels whose 3x3 neighbourhood holds no clipped pixel (:func:`pixel_depth`). Texture adds to the
    high-pass: an upper bound for a speckled image. Used when only one frame exists. Not floored."""
    x = image.astype(np.float64)
    hp = (x[:-2, :-2] - 2 * x[:-2, 1:-1] + x[:-2, 2:] - 2 * x[1:-1, :-2] + 4 * x[1:-1, 1:-1] - 2 * x[1:-1, 2:]
          + x[2:, :-2] - 2 * x[2:, 1:-1] + x[2:, 2:])
    clip = pixel_depth(image, effective_bits).clipped(image)
    rows, cols = hp.shape
    near = np.zeros(hp.shape, dtype=bool)
    for dy in range(3):
        for dx in range(3):
            near |= clip[dy:dy + rows, dx:dx + cols]
    hp = hp[~near]
    if hp.size == 0:
        raise RecordingError("noise estimate: every pixel of the frame is next to a clipped (saturated or black) one")
    med = np.median(hp)
    sigma = 1.4826 * float(np.median(np.abs(hp - med))) / 6.0
    return NoiseEstimate(sigma, "high-pass MAD of one frame", int(hp.size))


# ------------------------------------------------------------------------------ correlation estimate
@dataclass(frozen=True)
class SubsetMatches:
    """Subsets of frame a matched in frame b (:func:`match_subsets`): the per-subset noise variances
    ``s2`` (gray^2) of those used, and how many of ``n_subsets`` were left out: ``n_unmatched`` (no ZNCC
    peak >= 0.6 within the search, not converged, no texture, or over 2 % clipped pixels), ``n_identical`` (frame
    b repeats the subset's pixels exactly at the whole-pixel match)."""

    s2: np.ndarray
    n_subsets: int
    n_unmatched: int
    n_identical: int
    subset_px: int

    def describe(self) -> str:
        return (f"{len(self.s2)} of {self.n_subsets} {self.subset_px} px subsets matched ({self.n_identical} "
                f"repeated exactly and {self.n_unmatched} unmatched left out)")


def subset_grid(shape: tuple[int, int], subset_px: int = CORRELATION_SUBSET_PX) -> np.ndarray:
    """(N, 2) top-left corners (x, y) of non-overlapping subsets tiling the image inside the search and
    interpolation margins."""
    _, after = patch_margin(_INTERP_TAPS)
    m = CORRELATION_SEARCH_PX + after + 1
    ys = np.arange(m, shape[0] - subset_px - m + 1, subset_px)
    xs = np.arange(m, shape[1] - subset_px - m + 1, subset_px)
    return np.array([(x, y) for y in ys for x in xs], dtype=np.intp).reshape(-1, 2)


def interp_noise_gain(u: np.ndarray) -> np.ndarray:
    """(N,) white-noise variance gain gamma of the tracker's interpolant at displacements ``u`` (N, 2) px:
    sum of the squared weights along x times along y (1 at whole pixels)."""
    frac = np.asarray(u, dtype=np.float64) - np.floor(u)
    wx = kernel_weights(frac[:, 0], _INTERP_TAPS).astype(np.float64)
    wy = kernel_weights(frac[:, 1], _INTERP_TAPS).astype(np.float64)
    return (wx ** 2).sum(axis=1) * (wy ** 2).sum(axis=1)


def zncc_noise_var(zncc: np.ndarray, variance: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Noise variance (gray^2) of subsets of gray-level ``variance`` (gray^2) matched with ``zncc`` at
    displacement ``u`` (N, 2) px: 2 (1 - ZNCC) V / (1 + gamma) (module doc)."""
    return 2.0 * np.maximum(1.0 - np.asarray(zncc), 0.0) * variance / (1.0 + interp_noise_gain(u))


def _search_starts(a: np.ndarray, b: np.ndarray, corners: np.ndarray, subset_px: int, clip_a: np.ndarray,
                   clip_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per subset: its ZNCC peak in ``b`` (start displacement (x, y) px, NaN when none >= 0.6, on the window's
    border or over MAX_CLIPPED_SHARE clipped) and whether ``b`` repeats its pixels exactly there."""
    a32, b32 = a.astype(np.float32), b.astype(np.float32)
    starts = np.full((len(corners), 2), np.nan)
    identical = np.zeros(len(corners), dtype=bool)
    r, s = CORRELATION_SEARCH_PX, subset_px
    for i, (x, y) in enumerate(corners):
        if clip_a[y:y + s, x:x + s].mean() > MAX_CLIPPED_SHARE:
            continue
        hit = zncc_search(b32, a32[y:y + s, x:x + s], x - r, x + r, y - r, y + r)
        if hit is None or hit.on_border or not hit.zncc >= CORRELATION_ZNCC_MIN \
                or clip_b[hit.y:hit.y + s, hit.x:hit.x + s].mean() > MAX_CLIPPED_SHARE:
            continue
        starts[i] = (hit.x - x + hit.sub_dx, hit.y - y + hit.sub_dy)
        identical[i] = np.array_equal(a[y:y + s, x:x + s], b[hit.y:hit.y + s, hit.x:hit.x + s])
    return starts, identical


def _inside(corners: np.ndarray, subset_px: int, shape: tuple[int, int]) -> np.ndarray:
    before, after = patch_margin(_INTERP_TAPS)
    x, y = corners[:, 0], corners[:, 1]
    return (x >= before) & (y >= before) & (x + subset_px + after <= shape[1]) & (y + subset_px + after <= shape[0])


def match_subsets(a: np.ndarray, b: np.ndarray, corners: np.ndarray | None = None,
                  subset_px: int = CORRELATION_SUBSET_PX, *, effective_bits: int | None = None,
                  drop_identical: bool = True) -> SubsetMatches:
    """Match the subsets of ``a`` (top-left ``corners`` (N, 2) px; None: :func:`subset_grid`) in ``b``: ZNCC
    search +- CORRELATION_SEARCH_PX, then translation IC-GN (:class:`vibro_dic.icgn.IcgnBlocks`); each
    converged match of ZNCC >= 0.6 gives a noise variance (:func:`zncc_noise_var`). ``drop_identical``:
    leave out the subsets ``b`` repeats pixel for pixel (a lossy codec's copies)."""
    depth = pixel_depth(a, effective_bits)
    grid = subset_grid(a.shape, subset_px) if corners is None else np.asarray(corners, dtype=np.intp).reshape(-1, 2)
    grid = grid[_inside(grid, subset_px, a.shape)]
    n = len(grid)
    starts, identical = _search_starts(a, b, grid, subset_px, depth.clipped(a), depth.clipped(b))
    found = np.isfinite(starts).all(axis=1)
    if not found.any():
        return SubsetMatches(np.empty(0), n, n, 0, subset_px)
    blocks = IcgnBlocks(a.astype(np.float32), grid, (subset_px, subset_px), taps=_INTERP_TAPS, max_move_px=2.0)
    res = blocks.refine(b.astype(np.float32), np.where(found[:, None], starts, 0.0), active=found)
    ok = found & res.converged & (res.zncc >= CORRELATION_ZNCC_MIN)
    copies = ok & identical if drop_identical else np.zeros(n, dtype=bool)
    keep = ok & ~copies
    variance = blocks.df[keep] ** 2 / (subset_px * subset_px)
    return SubsetMatches(zncc_noise_var(res.zncc[keep], variance, res.u[keep]), n, int(n - ok.sum()),
                         int(copies.sum()), subset_px)


def noise_from_correlation(a: np.ndarray, b: np.ndarray, corners: np.ndarray | None = None,
                           subset_px: int = CORRELATION_SUBSET_PX, *, effective_bits: int | None = None,
                           drop_identical: bool = True, why: str = "") -> NoiseEstimate:
    """Noise std (gray levels) the correlation sees between frames ``a`` and ``b``: the median over the
    matched subsets (:func:`match_subsets`) of 2 (1 - ZNCC) V / (1 + gamma) (module doc). ``why``: the
    reason the frame difference was not used, for the method string. Raises :class:`TextureError` with the
    numbers when fewer than MIN_CORRELATION_SUBSETS subsets are left. Not floored."""
    m = match_subsets(a, b, corners, subset_px, effective_bits=effective_bits, drop_identical=drop_identical)
    if len(m.s2) < MIN_CORRELATION_SUBSETS:
        raise TextureError(f"noise estimate refused: {why + ', and ' if why else ''}only {m.describe()} between "
                           f"the two frames (need {MIN_CORRELATION_SUBSETS}; a match: ZNCC >= "
                           f"{CORRELATION_ZNCC_MIN:g} within +-{CORRELATION_SEARCH_PX} px, at most "
                           f"{100 * MAX_CLIPPED_SHARE:g} % clipped pixels): record losslessly (image files, FFV1, "
                           "the camera's own file) or with less compression")
    return _correlation_estimate(m, why)


def _correlation_estimate(m: SubsetMatches, why: str) -> NoiseEstimate:
    sigma = math.sqrt(float(np.median(m.s2)))
    return NoiseEstimate(sigma, f"ZNCC of matched subsets, not the frame difference: s^2 = 2 (1 - ZNCC) V / "
                                f"(1 + gamma), median over {m.describe()}" + (f"; because {why}" if why else ""),
                         len(m.s2) * m.subset_px * m.subset_px)


# ------------------------------------------------------------------------------ the estimate the check uses
def floor_noise(estimate: NoiseEstimate, depth: PixelDepth) -> NoiseEstimate:
    """``estimate`` raised to the quantization noise of ``depth`` when below it (module doc)."""
    q = depth.quantization_sigma_gray
    if math.isfinite(estimate.sigma_gray) and estimate.sigma_gray >= q:
        return estimate
    return replace(estimate, sigma_gray=q, method=f"{estimate.method}; measured {estimate.sigma_gray:.3g} gray levels, "
                                                  f"floored at the quantization noise {q:.3g} of {depth.describe()} "
                                                  "(one code / sqrt(12))")


def estimate_noise(reference: np.ndarray, second: np.ndarray | None = None, *, effective_bits: int | None = None,
                   codec: str | None = None, corners: np.ndarray | None = None,
                   subset_px: int = CORRELATION_SUBSET_PX) -> NoiseEstimate:
    """Image noise std (gray levels of the delivered pixels) for the texture check (module doc).

    ``reference``, ``second``: frames 0 and 1 (``second`` None: the one-frame estimate); ``effective_bits``:
    significant bits (:attr:`vibro_io.frames.FrameSequence.effective_bits`; None: :func:`pixel_depth`
    infers them); ``codec``: the video's FourCC (:attr:`vibro_io.frames.FrameSequence.codec`; "" for image
    and camera files, None when unknown); ``corners`` (N, 2) px: top-left corners of the DIC subsets of
    side ``subset_px`` for the correlation estimate (None: a grid over the image).
    The frame difference unless the codec is lossy or the difference is degenerate, then the correlation
    estimate; a lossy video whose frames give too few matched, changed subsets is refused
    (:class:`TextureError`); never below the quantization noise (:func:`floor_noise`).
    """
    ref = np.asarray(reference)
    depth = pixel_depth(ref, effective_bits)
    lossy = codec_is_lossy(codec)
    if second is None or np.shape(second) != ref.shape or (not lossy and np.array_equal(second, ref)):
        return floor_noise(noise_from_image(ref, effective_bits=depth.effective_bits), depth)
    b = np.asarray(second)
    diff, why = None, f"the frames come from a lossy video codec ({codec!r})" if lossy else None
    if not lossy:
        try:
            diff = noise_from_frames(ref, b, effective_bits=depth.effective_bits)
            why = degenerate_reason(diff, depth)
        except RecordingError as exc:
            why = str(exc)
        if why is None:
            return floor_noise(diff, depth)
    # a copy is evidence of nothing unless the frames are known to be lossless
    kw = dict(effective_bits=depth.effective_bits, drop_identical=codec is None or lossy)
    if lossy:
        return floor_noise(noise_from_correlation(ref, b, corners, subset_px, why=why, **kw), depth)
    m = match_subsets(ref, b, corners, subset_px, **kw)
    if len(m.s2) >= MIN_CORRELATION_SUBSETS:
        return floor_noise(_correlation_estimate(m, why), depth)
    sigma = diff.sigma_gray if diff is not None else 0.0
    return floor_noise(NoiseEstimate(sigma, f"{why}; and the correlation had only {m.describe()}", 0), depth)


@dataclass(kw_only=True)
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

    def sigma_problem(self) -> str | None:
        """Why the predicted sigma of this body's mesh is impossible (0 px or not a number), or None."""
        m = self.mesh_sigma_px
        if np.all(np.isfinite(m)) and np.all(m > 0):
            return None
        return (f"dic.{self.name}_roi {self.roi.as_list()}: predicted displacement sigma of the mesh "
                f"{[float(v) for v in m]} px (x, y): 0 px or not a number is impossible (no noise, or no gradient)")

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
        refused += [m for m in (b.sigma_problem() for b in self.bodies.values() if not b.refused) if m]
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


def assess_body(name: str, reference: np.ndarray, dic: DicConfig, noise: NoiseEstimate, *,
                max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX, min_valid_fraction: float = 0.5,
                grad_xy: tuple[np.ndarray, np.ndarray] | None = None) -> BodyTexture:
    """Texture of body ``name``'s mesh (rig.yaml ``dic``: its ``{name}_roi``, subset size and mesh step, px) in
    ``reference`` (2-D, gray levels) against ``noise``."""
    roi: Roi = getattr(dic, f"{name}_roi")
    subset_px, step_px = dic.subset_px, dic.mesh_step_px
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
    body = BodyTexture(name=name, roi=roi, subset_px=subset_px, points=points, sssig=sssig, sssig_noise=sssig_noise,
                       sigma_px=sigma, usable=usable,
                       min_usable=max(1, math.ceil(min_valid_fraction * n - 1e-9)),
                       max_subset_sigma_px=max_subset_sigma_px, variance=variance)
    if usable.any():
        body.mesh_sigma_px = mesh_sigma_px((gx, gy), corners[usable], subset_px, sssig[usable], s)
    return body


def assess_texture(reference: np.ndarray, dic: DicConfig, noise: NoiseEstimate, *,
                   max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX,
                   min_valid_fraction: float = 0.5) -> TextureReport:
    """Texture of the ball's and the structure's meshes (rig.yaml ``dic``) in the reference frame. A noise
    that is not a positive number would predict 0 px (or nothing) of DIC error: refused (:class:`TextureError`)."""
    if not (math.isfinite(max_subset_sigma_px) and max_subset_sigma_px > 0):
        raise RecordingError(f"max_subset_sigma_px must be a positive number (px), got {max_subset_sigma_px!r}")
    if not (math.isfinite(noise.sigma_gray) and noise.sigma_gray > 0):
        raise TextureError(f"texture check refused the tracking: image noise of {noise.describe()}: a noise that "
                           "is not a positive number predicts a DIC error of 0 px (or none), which is impossible; "
                           "give integer (8- or 16-bit) frames, whose quantization bounds the noise from below")
    grad = gradients(np.asarray(reference))
    bodies = {name: assess_body(name, reference, dic, noise, max_subset_sigma_px=max_subset_sigma_px,
                                min_valid_fraction=min_valid_fraction, grad_xy=grad)
              for name in _mesh_bodies(dic)}
    if dic.ball_method == "outline":  # a plain ball: its outline's accuracy instead (vibro_dic.outline)

        bodies = {"ball": assess_outline("ball", reference, dic.ball_roi, noise.sigma_gray,
                                         max_sigma_px=max_subset_sigma_px, min_valid_fraction=min_valid_fraction),
                  **bodies}
    return TextureReport(noise, bodies)


def _mesh_bodies(dic: DicConfig) -> tuple[str, ...]:
    """The bodies tracked by a DIC mesh of subsets: both, or the structure alone when the ball is tracked by
    its outline (rig.yaml ``dic.ball_method``)."""
    return ("structure",) if dic.ball_method == "outline" else ("ball", "structure")


def mesh_corners(dic: DicConfig) -> np.ndarray:
    """(N, 2) top-left corners (x, y) px of the ball's and the structure's DIC subsets (the structure's alone
    when the ball is tracked by its outline)."""
    half = dic.subset_px // 2
    return np.vstack([mesh_points(getattr(dic, f"{name}_roi"), dic.subset_px, dic.mesh_step_px) - half
                      for name in _mesh_bodies(dic)]).astype(np.intp)


def check_texture(reference: np.ndarray, second: np.ndarray | None, dic: DicConfig, *,
                  max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX,
                  min_valid_fraction: float = 0.5, effective_bits: int | None = None,
                  codec: str | None = None) -> tuple[TextureReport, list[str]]:
    """The texture check before tracking (the CLI's and the node's): noise from ``reference`` and ``second``
    (another frame; None or the same pixels: the one-frame estimate) by :func:`estimate_noise` (the frames'
    ``effective_bits`` and video ``codec`` as :class:`vibro_io.frames.FrameSequence` gives them; None:
    unknown), then :func:`assess_texture`. Returns (report, warnings); raises :class:`TextureError` when a
    body has too few usable subsets or the noise cannot be estimated."""
    ref = np.asarray(reference)
    noise = estimate_noise(ref, second, effective_bits=effective_bits, codec=codec,
                           corners=mesh_corners(dic), subset_px=dic.subset_px)
    report = assess_texture(ref, dic, noise, max_subset_sigma_px=max_subset_sigma_px,
                            min_valid_fraction=min_valid_fraction)
    return report, report.check()
