"""The texture check's image noise on real and lossy frames: it can never be 0.

- A real Photron file (../shared/validation/lab_files/ball_12bit, 12 bits delivered MSB-aligned in uint16):
  its saturated backlight sits at 4095 << 4 = 65520, not at the dtype's 65535; judged against the file's
  effective depth it is clipped, and the noise comes from the rest.
- A lossy video (the first of avc1, H264, X264, mp4v, MJPG this OpenCV build writes and reads back; with
  the pinned opencv-python-headless 5.0 wheel, which has no H.264 encoder, that is mp4v, MPEG-4 part 2,
  read back as FourCC "FMP4") of a speckled synthetic recording with known noise: the codec leaves
  identical pixels (the fault seen on a real H.264 video), so the frame difference is degenerate and the
  estimate comes from the correlation of the DIC subsets.
- The same recording in FFV1 (lossless): the frame difference recovers the noise.
- A noise-free pair: the noise is the quantization floor and the predicted DIC sigma is above 0.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from vibro_dic.init_rig import InitError, noise_sigma_gray, to_gray255
from vibro_dic.speckle import speckle_pattern
from vibro_dic.texture import (
    NOISE_BLOCK_PX,
    TextureError,
    assess_texture,
    check_texture,
    degenerate_reason,
    estimate_noise,
    mesh_corners,
    noise_from_frames,
    pixel_depth,
)
from vibro_io.frames import FrameSequence
from vibro_io.rig import CameraConfig, DicConfig, Roi

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
BALL_12BIT = SHARED / "validation" / "lab_files" / "ball_12bit.cihx"
CAMERA = CameraConfig(fps=1000.0, t0_s=0.0, mm_per_px=1.0)  # the time base plays no part here

SHAPE = (160, 480)
NOISE = 2.0  # gray levels, added before rounding to uint8
TRUE_NOISE = math.sqrt(NOISE ** 2 + 1.0 / 12.0)  # plus the uniform rounding error of one 8-bit code
SUBSET_PX = 31
# ball 61x61 px (16 subsets) on the speckle that moves down 1 px per frame; structure 81x61 px (24) on static speckle
DIC = DicConfig(SUBSET_PX, 10, Roi(370, 50, 61, 61), Roi(200, 50, 81, 61))
N_BALL_SUBSETS = 16
LOSSY_CANDIDATES = (("avc1", ".mp4"), ("H264", ".mp4"), ("X264", ".mp4"), ("mp4v", ".mp4"), ("MJPG", ".avi"))


# --- the real Photron file ---------------------------------------------------------------------------------
def _sixteen_px_blocks(mask: np.ndarray) -> np.ndarray:
    """(n_blocks,) True where a 16 px block (as the estimator cuts them) holds a True pixel."""
    b = NOISE_BLOCK_PX
    rows, cols = (mask.shape[0] // b) * b, (mask.shape[1] // b) * b
    return mask[:rows, :cols].reshape(rows // b, b, cols // b, b).any(axis=(1, 3)).ravel()


def test_ball_12bit_saturation_is_judged_against_its_12_bits_and_its_noise_is_measured() -> None:
    seq = FrameSequence(BALL_12BIT, CAMERA)
    frames = np.stack([f.image for f in seq])
    assert seq.effective_bits == 12 and seq.codec == "" and frames.dtype == np.uint16
    top = 65535 - (2 ** (16 - 12) - 1)  # 4095 << 4 = 65520, the brightest code of a 12-bit camera
    depth = pixel_depth(frames[0], seq.effective_bits)
    assert depth.brightest_gray == top
    # README: "most of the image is the saturated backlight: 4095 in 12 bits" (78 % of frame 0); none of it is
    # at the dtype's 65535, which is what made the old clipping test see no saturation at all
    assert np.mean(depth.saturated(frames[0])) > 0.7
    assert np.mean(frames[0] == top) == np.mean(depth.saturated(frames[0]))
    assert not np.any(frames[0] == 65535)

    est = estimate_noise(frames[0], frames[1], effective_bits=seq.effective_bits, codec=seq.codec)
    assert est.method.startswith("difference of two frames")
    # a measured noise: above the 12-bit quantization floor (16 / sqrt(12) = 4.6 in uint16 gray levels), not 0
    assert est.sigma_gray > depth.quantization_sigma_gray > 0
    # it rests only on blocks without a saturated pixel in either frame
    unsaturated = ~_sixteen_px_blocks((frames[0] >= top) | (frames[1] >= top))
    assert 0 < est.n_pixels <= NOISE_BLOCK_PX ** 2 * int(unsaturated.sum())
    # against an independent measurement: the temporal noise over the 15 frames of the blocks never clipped. Noise
    # rises with the gray level (shot noise) and moving edges add to it, so the quietest block bounds the static
    # estimate from below: no static block is quieter. Each block's temporal sigma rests on 256 px x 14 degrees
    # of freedom: relative standard error 1 / sqrt(2 * 3584) = 1.2 %; 5 of them = 6 %.
    never = ~_sixteen_px_blocks(depth.clipped(frames).any(axis=0))
    b = NOISE_BLOCK_PX
    rows, cols = (frames.shape[1] // b) * b, (frames.shape[2] // b) * b
    var_t = frames[:, :rows, :cols].astype(np.float64).var(axis=0, ddof=1)
    block_sigma = np.sqrt(var_t.reshape(rows // b, b, cols // b, b).mean(axis=(1, 3)).ravel()[never])
    assert est.sigma_gray >= (1 - 0.06) * block_sigma.min()


def test_init_noise_on_ball_12bit_leaves_the_saturated_backlight_out() -> None:
    frame0 = next(iter(FrameSequence(BALL_12BIT, CAMERA))).image
    gray = to_gray255(frame0)  # vibro init's 0..255 scale: 65520 / 257 = 254.94
    backlight = frame0 >= 65535 - (2 ** (16 - 12) - 1)
    for bits in (12, None):  # None: the 254.5 threshold catches a 16-bit source's top code without metadata
        # the backlight alone has no noise to see: refused, where it used to measure 0 gray levels
        with pytest.raises(InitError, match="no unclipped pixel"):
            noise_sigma_gray(gray, backlight, effective_bits=bits)
        # the whole frame gives the noise of its unsaturated part only
        assert noise_sigma_gray(gray, None, effective_bits=bits) == noise_sigma_gray(gray, ~backlight,
                                                                                     effective_bits=bits) > 0


# --- synthetic recordings through a video codec ------------------------------------------------------------
_STRUCTURE = speckle_pattern(SHAPE, std=30.0, seed=1)  # std 30 about 128: 4.3 sigma from 0 and 255, never clipped
_BALL = speckle_pattern(SHAPE, std=30.0, seed=2)


def _clean(k: int) -> np.ndarray:
    """Noise-free frame k (float gray levels): a flat static background (columns < 160), static speckle (the
    structure, 160..319) and speckle moving down k px (the ball, >= 320): whole pixels, so the truth needs
    no interpolation."""
    img = np.full(SHAPE, 90.0)
    img[:, 160:320] = _STRUCTURE.render()[:, 160:320]
    img[:, 320:] = _BALL.render(0.0, float(k))[:, 320:]
    return img


def _record(path: Path, fourcc: str, n_frames: int = 6, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Write ``n_frames`` noisy uint8 frames with ``fourcc``; returns (clean frames, added noise); [] when this
    OpenCV build cannot write it."""
    rng = np.random.default_rng(seed)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 1000.0, (SHAPE[1], SHAPE[0]), isColor=False)
    if not writer.isOpened():
        return [], []
    clean, noise = [], []
    for k in range(n_frames):
        c, n = _clean(k), rng.standard_normal(SHAPE) * NOISE
        writer.write(np.clip(np.rint(c + n), 0, 255).astype(np.uint8))
        clean.append(c)
        noise.append(n)
    writer.release()
    return clean, noise


def _lossy_video(tmp_path: Path) -> tuple[FrameSequence, list[np.ndarray], list[np.ndarray]]:
    for fourcc, ext in LOSSY_CANDIDATES:
        path = tmp_path / f"video_{fourcc}{ext}"
        clean, noise = _record(path, fourcc)
        if clean and cv2.VideoCapture(str(path)).read()[0]:
            return FrameSequence(path, CAMERA), clean, noise
    raise AssertionError(f"this OpenCV build writes none of {[c for c, _ in LOSSY_CANDIDATES]}")


def _subset_views(image: np.ndarray, shift_ball_px: int) -> list[np.ndarray]:
    """The DIC subsets of ``image`` (ball first), the ball's moved down ``shift_ball_px``."""
    out = []
    for i, (x, y) in enumerate(mesh_corners(DIC)):
        dy = shift_ball_px if i < N_BALL_SUBSETS else 0
        out.append(image[y + dy:y + dy + SUBSET_PX, x:x + SUBSET_PX].astype(np.float64))
    return out


def test_lossy_video_noise_comes_from_the_correlation_and_is_what_the_frames_differ_by(tmp_path) -> None:
    seq, clean, noise = _lossy_video(tmp_path)
    d0, d1 = (f.image for f in seq.iter_slots(0, 2))
    depth = pixel_depth(d0, seq.effective_bits)
    # the fault: the codec repeats the static pixels, so the frame difference is degenerate (0, or mostly exact
    # zeros), where the sensor's noise of 2 gray levels would leave ~14 % exact zeros (erf(1 / (4 * 2.02)))
    assert degenerate_reason(noise_from_frames(d0, d1), depth) is not None

    est = estimate_noise(d0, d1, effective_bits=seq.effective_bits, codec=seq.codec, corners=mesh_corners(DIC),
                         subset_px=SUBSET_PX)
    assert "not the frame difference" in est.method and "lossy video codec" in est.method
    assert est.sigma_gray > depth.quantization_sigma_gray > 0

    # The truth, from the pixels at the known whole-pixel shift (ball 1 px down, structure 0): per subset half the
    # variance of the matched difference, the noise a correlation of these two frames sees; median over subsets as
    # the estimator pools. The ZNCC form 2 (1 - ZNCC) V / (1 + gamma) equals it up to (a) its normalisation by each
    # frame's own subset variance, second order in their relative difference (the codec's error, ~3.5^2 gray^2,
    # over a subset variance of ~900 gray^2: < 1 %), (b) the matched shift's own error (~sqrt(2) * 1.2 / sqrt(SSSIG)
    # ~0.004 px: (0.004 px)^2 * SSSIG / 961 px, < 0.1 %) and (c) gamma at that shift (1 - 1e-4): 5 % is ample.
    r = [b - a for a, b in zip(_subset_views(d0, 0), _subset_views(d1, 1))]
    truth = math.sqrt(float(np.median([0.5 * x.var() for x in r])))
    assert est.sigma_gray == pytest.approx(truth, rel=0.05)

    # Against the codec's behaviour (t_k = decoded - noise-free frame k, per subset): the difference r = t_1 - t_0
    # is at most rms(t_0) + rms(t_1) (Minkowski), and at least the share kappa of frame 1's own new noise n_1
    # that the codec kept (t_0 is decoded before n_1 exists: var(r) >= kappa^2 var(n_1), Cauchy-Schwarz).
    t0 = _subset_views(d0.astype(np.float64) - clean[0], 0)
    t1 = _subset_views(d1.astype(np.float64) - clean[1], 1)
    n1 = _subset_views(noise[1], 1)
    upper = max((math.sqrt(np.mean(a ** 2)) + math.sqrt(np.mean(b ** 2))) / math.sqrt(2) for a, b in zip(t0, t1))
    kappa = min(float(np.sum(b * n) / np.sum(n * n)) for b, n in zip(t1, n1))
    assert kappa * NOISE / math.sqrt(2) * 0.95 <= est.sigma_gray <= upper * 1.05


def test_lossless_ffv1_frame_difference_recovers_the_noise(tmp_path) -> None:
    path = tmp_path / "video_ffv1.avi"
    clean, noise = _record(path, "FFV1")
    assert clean, "this OpenCV build cannot write FFV1"
    seq = FrameSequence(path, CAMERA)
    d0, d1 = (f.image for f in seq.iter_slots(0, 2))
    assert np.array_equal(d0, np.clip(np.rint(clean[0] + noise[0]), 0, 255))  # lossless indeed
    est = estimate_noise(d0, d1, effective_bits=seq.effective_bits, codec=seq.codec, corners=mesh_corners(DIC),
                         subset_px=SUBSET_PX)
    assert est.method.startswith("difference of two frames")
    # pooled variance of n_pixels differences, each 16x16 block losing one degree of freedom to its mean: relative
    # standard error of sigma 1 / sqrt(2 * dof); the pooled blocks are every static one (noise-only blocks scatter
    # 8.9 %, far inside the 1.3^2 x 5 %-quantile cut), so no selection bias: 5 standard errors
    dof = est.n_pixels * (NOISE_BLOCK_PX ** 2 - 1) / NOISE_BLOCK_PX ** 2
    assert est.sigma_gray == pytest.approx(TRUE_NOISE, rel=5.0 / math.sqrt(2.0 * dof))


# --- no noise at all ---------------------------------------------------------------------------------------
def _noise_free_pair(ball_shift_px: float) -> tuple[np.ndarray, np.ndarray]:
    """uint8 frames without noise: flat 100 except two speckle patches under the ROIs (26 % of the image, so the
    one-frame high-pass's median is 0); the ball's patch moved down ``ball_shift_px`` in the second."""
    frames = []
    for shift in (0.0, ball_shift_px):
        img = np.full(SHAPE, 100.0)
        img[30:130, 170:270] = _STRUCTURE.render()[30:130, 170:270]
        img[30:130, 350:450] = _BALL.render(0.0, shift)[30:130, 350:450]
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return frames[0], frames[1]


@pytest.mark.parametrize("ball_shift_px", [0.0, 0.4])
def test_a_noise_free_pair_predicts_the_quantization_floor_never_zero(ball_shift_px: float) -> None:
    a, b = _noise_free_pair(ball_shift_px)
    report, _ = check_texture(a, b, DIC)
    floor = 1.0 / math.sqrt(12.0)  # one 8-bit code, rounding error uniform over it
    assert report.noise.sigma_gray >= floor
    for body in report.bodies.values():
        assert np.all(np.isfinite(body.mesh_sigma_px)) and np.all(body.mesh_sigma_px > 0), body.name
        assert np.all(body.sigma_px[body.usable] > 0)


def test_a_zero_noise_on_float_frames_is_refused() -> None:
    a, _ = _noise_free_pair(0.0)
    img = a.astype(np.float64)  # float pixels: no code grid, no quantization floor
    noise = estimate_noise(img, img.copy())
    assert noise.sigma_gray == 0.0
    with pytest.raises(TextureError, match="0 px"):
        assess_texture(img, DIC, noise)
