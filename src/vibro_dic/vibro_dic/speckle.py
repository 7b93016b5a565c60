"""Synthetic speckle images with EXACT sub-pixel shifts, for tests and benchmarks.

A speckle pattern is white noise low-pass filtered by a Gaussian of ``blur_px``
(std, pixels). Its spectrum at the Nyquist frequency is exp(-pi^2 blur_px^2 / 2)
(1.5e-5 for blur_px = 1.5): the pattern is band-limited, so a Fourier phase ramp
shifts it exactly by any sub-pixel amount (periodic boundary).

Shift convention (as DIC's u, v): content at (x, y) in the reference appears at
(x + dx, y + dy) in the shifted image; x = column, y = row (rows grow downward,
so "up" by d px is dy = -d).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SpecklePattern:
    """A band-limited pattern held as its spectrum; ``render(dx, dy)`` gives a shifted copy (float gray levels)."""

    spectrum: np.ndarray  # rfft2 of the zero-shift image
    shape: tuple[int, int]

    def render(self, dx: float = 0.0, dy: float = 0.0) -> np.ndarray:
        """Float image (rows, cols) of the pattern shifted by (dx, dy) px, exact for a band-limited pattern."""
        rows, cols = self.shape
        fy = np.fft.fftfreq(rows)[:, None]
        fx = np.fft.rfftfreq(cols)[None, :]
        ramp = np.exp(-2j * np.pi * (fx * dx + fy * dy))
        return np.fft.irfft2(self.spectrum * ramp, s=self.shape)


def speckle_pattern(shape: tuple[int, int], *, blur_px: float = 1.5, mean: float = 128.0,
                    std: float = 45.0, seed: int | None = 0) -> SpecklePattern:
    """Random band-limited speckle of ``shape`` (rows, cols) with given gray-level mean and std."""
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(shape)
    rows, cols = shape
    fy = np.fft.fftfreq(rows)[:, None]
    fx = np.fft.rfftfreq(cols)[None, :]
    spec = np.fft.rfft2(noise) * np.exp(-2.0 * np.pi**2 * blur_px**2 * (fx**2 + fy**2))
    # strictly band-limited: no energy at the Nyquist frequency, whose phase a real image cannot shift
    if cols % 2 == 0:
        spec[:, -1] = 0.0
    if rows % 2 == 0:
        spec[rows // 2, :] = 0.0
    img = np.fft.irfft2(spec, s=shape)
    scale = std / img.std()
    spec = spec * scale
    spec[0, 0] = mean * rows * cols  # DC term sets the mean exactly
    return SpecklePattern(spectrum=spec, shape=(rows, cols))


def add_noise(image: np.ndarray, sigma: float, rng: np.random.Generator | None = None,
              dtype: type | None = np.uint8) -> np.ndarray:
    """Add Gaussian noise of std ``sigma`` (gray levels); round and clip to ``dtype`` unless None."""
    rng = rng if rng is not None else np.random.default_rng()
    out = image + (rng.standard_normal(image.shape) * sigma if sigma > 0 else 0.0)
    if dtype is None:
        return out
    info = np.iinfo(dtype)
    return np.clip(np.rint(out), info.min, info.max).astype(dtype)


def shifted_pair(shape: tuple[int, int], dx: float, dy: float, *, noise_sigma: float = 0.0,
                 blur_px: float = 1.5, seed: int = 0, dtype: type | None = np.uint8
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(reference, shifted) images of one pattern, shifted by (dx, dy) px, each with independent noise."""
    pat = speckle_pattern(shape, blur_px=blur_px, seed=seed)
    rng = np.random.default_rng(seed + 1)
    return (add_noise(pat.render(), noise_sigma, rng, dtype),
            add_noise(pat.render(dx, dy), noise_sigma, rng, dtype))


def disk_mask(shape: tuple[int, int], cx: float, cy: float, radius: float) -> np.ndarray:
    """Anti-aliased disk coverage in [0, 1] (1-px linear edge) centred at (cx, cy) px."""
    rows, cols = shape
    yy, xx = np.mgrid[0:rows, 0:cols]
    r = np.hypot(xx - cx, yy - cy)
    return np.clip(radius + 0.5 - r, 0.0, 1.0)


class RigScene:
    """A rig-like scene for moving-speckle sequences: a speckled structure and a speckled ball.

    Columns < ``split_col`` show the structure's pattern; columns >= ``split_col`` show a
    dark cavity holding a speckled ball disk of ``ball_radius_px`` centred at
    (``ball_x_px``, ``ball_y0_px``) in frame 0. ``frame(ball_up_px, structure_up_px)``
    renders both bodies moved UP (towards row 0) by the given amounts in px, exactly.
    """

    def __init__(self, shape: tuple[int, int] = (160, 480), *, split_col: int = 240,
                 ball_x_px: float = 360.0, ball_y0_px: float = 80.0, ball_radius_px: float = 45.0,
                 blur_px: float = 1.5, seed: int = 0, background: float = 20.0):
        self.shape = shape
        self.split_col = split_col
        self.ball_x_px, self.ball_y0_px, self.ball_radius_px = ball_x_px, ball_y0_px, ball_radius_px
        self.background = background
        self.structure = speckle_pattern(shape, blur_px=blur_px, seed=seed)
        self.ball = speckle_pattern(shape, blur_px=blur_px, seed=seed + 1000)

    def frame(self, ball_up_px: float, structure_up_px: float, *, noise_sigma: float = 0.0,
              rng: np.random.Generator | None = None, dtype: type | None = np.uint8) -> np.ndarray:
        """One image with the ball moved up by ``ball_up_px`` and the structure by ``structure_up_px``."""
        s = self.structure.render(0.0, -structure_up_px)
        b = self.ball.render(0.0, -ball_up_px)
        m = disk_mask(self.shape, self.ball_x_px, self.ball_y0_px - ball_up_px, self.ball_radius_px)
        img = self.background * (1.0 - m) + b * m
        img[:, : self.split_col] = s[:, : self.split_col]
        return add_noise(img, noise_sigma, rng, dtype)

    def blurred_frame(self, ball_up_px: np.ndarray, structure_up_px: np.ndarray, *, noise_sigma: float = 0.0,
                      rng: np.random.Generator | None = None, dtype: type | None = np.uint8) -> np.ndarray:
        """Motion-blurred image: the mean of noise-free renders at the sub-exposure positions
        ``ball_up_px[i]``, ``structure_up_px[i]`` (px up), then noise and rounding."""
        acc = np.zeros(self.shape)
        for b, s in zip(ball_up_px, structure_up_px):
            acc += self.frame(float(b), float(s), dtype=None)
        return add_noise(acc / len(ball_up_px), noise_sigma, rng, dtype)


def scene_rois(scene: RigScene) -> tuple[list[int], list[int]]:
    """(ball_roi, structure_roi) [x, y, w, h] for a :class:`RigScene` with 31 px subsets, 10 px step:
    ball 61x61 centred on the ball (16 points); structure 81x61 (24 points) centred in the
    structure strip, or 51x101 (also 24 points) when the strip is narrower than 89 px."""
    rows = scene.shape[0]
    ball = [int(round(scene.ball_x_px)) - 30, int(round(scene.ball_y0_px)) - 30, 61, 61]
    if scene.split_col >= 89:
        structure = [scene.split_col // 2 - 40, rows // 2 - 30, 81, 61]
    else:
        structure = [max(0, scene.split_col // 2 - 25), rows // 2 - 50, 51, 101]
    return ball, structure


def scene_rig_mapping(scene: RigScene, *, fps: float = 1000.0, mm_per_px: float = 0.05,
                      subset_px: int = 31, step_px: int = 10) -> dict:
    """A rig.yaml mapping for a :class:`RigScene` (ROIs from :func:`scene_rois`, 40 mesh points)."""
    ball_roi, structure_roi = scene_rois(scene)
    return {
        "camera": {"fps": fps, "t0_s": 0.0, "mm_per_px": mm_per_px},
        "ball": {"mass_kg": 1.82e-4, "diameter_mm": 4.77, "youngs_modulus_pa": 3.1e11, "poisson_ratio": 0.27},
        "structure": {"gap_mm": 16.6, "mass_kg": 0.663, "youngs_modulus_pa": 7.0e10, "poisson_ratio": 0.33},
        "excitation": {"frequency_hz": 22.0},
        "dic": {"subset_px": subset_px, "mesh_step_px": step_px,
                "ball_roi": ball_roi, "structure_roi": structure_roi},
    }


def write_scene_recording(out_dir, scene: RigScene, ball_up_px: np.ndarray, structure_up_px: np.ndarray, *,
                          noise_sigma: float = 2.0, seed: int = 0, fps: float = 1000.0,
                          mm_per_px: float = 0.05) -> None:
    """Write a recording (rig.yaml + frames/NNNNNN.png, 8-bit) of ``scene`` moving UP by the
    given per-frame amounts (px). Frames are rendered and written one at a time."""
    from pathlib import Path

    import cv2
    import yaml

    out = Path(out_dir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    (out / "rig.yaml").write_text(
        yaml.safe_dump(scene_rig_mapping(scene, fps=fps, mm_per_px=mm_per_px), sort_keys=False), encoding="utf-8")
    rng = np.random.default_rng(seed)
    for k, (b, s) in enumerate(zip(ball_up_px, structure_up_px)):
        cv2.imwrite(str(out / "frames" / f"{k:06d}.png"), scene.frame(float(b), float(s), noise_sigma=noise_sigma,
                                                                        rng=rng))
