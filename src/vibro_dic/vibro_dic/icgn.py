"""Inverse-compositional Gauss-Newton (IC-GN) sub-pixel refinement, translation warp, ZNSSD criterion.

For each block i (a DIC subset, or a whole mesh's bounding box) with reference f
(frame 0) and current image g, find the translation u = (ux, uy) (px, x = column,
y = row) minimising the zero-normalised SSD

    C(u) = sum_j [ (f_j - f_mean)/df - (g(x_j + u) - g_mean)/dg ]^2,   df, dg = L2 norms,

which equals 2 (1 - ZNCC) and is insensitive to gain and offset of the lighting.
Inverse composition keeps the Hessian H = sum J^T J with J = grad f constant, so it is
computed once per block (Pan et al. 2013). Per iteration, with e = f~ - (df/dg) g~,

    u <- u + H^-1 sum_j J_j^T e_j       (translation: W(u) o W(dp)^-1 = u - dp).

g is sampled with the separable Keys interpolants of :mod:`vibro_dic.interp`; all
blocks are solved together (vectorised, batched BLAS). Reference gradients are
4th-order central differences of frame 0.

Convergence: a block has converged when the step it just took is below ``tol_px``.
Gauss-Newton on this zero-residual problem converges quadratically near the
optimum, so the error left after a step of size s is O(s^2): with tol_px = 0.02
that is ~4e-4 px, far below the 0.01 px accuracy goal (checked in the tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .interp import sample_blocks, support_inside

_D4 = np.array([[1.0, -8.0, 0.0, 8.0, -1.0]], dtype=np.float32) / 12.0


def gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d/dx, d/dy) of an image by 4th-order central differences (gray levels per px), float32."""
    img = image.astype(np.float32, copy=False)
    gx = cv2.filter2D(img, cv2.CV_32F, _D4, borderType=cv2.BORDER_REFLECT_101)
    gy = cv2.filter2D(img, cv2.CV_32F, _D4.T, borderType=cv2.BORDER_REFLECT_101)
    return gx, gy


def extract_blocks(image: np.ndarray, x0: np.ndarray, y0: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(N, h, w) float32 copies of integer-position blocks with top-left (x0[i], y0[i])."""
    windows = np.lib.stride_tricks.sliding_window_view(image, size)
    return windows[np.asarray(y0, dtype=np.intp), np.asarray(x0, dtype=np.intp)].astype(np.float32)


@dataclass
class IcgnResult:
    """Per-block outcome: displacement u (N, 2) px (x, y), zncc (N,), converged (N,) bool, iterations used."""

    u: np.ndarray
    zncc: np.ndarray
    converged: np.ndarray
    iterations: int


class IcgnBlocks:
    """Precomputed reference blocks and inverse Hessians for translation IC-GN.

    ``corners``: (N, 2) integer top-left pixels (x, y) of the blocks in the reference;
    ``size``: (h, w) in px (a square DIC subset has h = w = subset_px).
    """

    def __init__(self, reference: np.ndarray, corners: np.ndarray, size: tuple[int, int], *,
                 taps: int = 6, max_iter: int = 10, tol_px: float = 0.02, max_move_px: float = 2.0):
        ref = reference.astype(np.float32, copy=False)
        self.corners = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
        self.size = (int(size[0]), int(size[1]))
        self.taps = taps
        self.max_iter = max_iter
        self.tol_px = tol_px
        self.max_move_px = max_move_px
        n = len(self.corners)
        x0, y0 = self.corners[:, 0], self.corners[:, 1]
        f = extract_blocks(ref, x0, y0, self.size).reshape(n, -1)
        gx, gy = gradients(ref)
        self.fx = extract_blocks(gx, x0, y0, self.size).reshape(n, -1)
        self.fy = extract_blocks(gy, x0, y0, self.size).reshape(n, -1)
        self.f_tilde = f - f.mean(axis=1, keepdims=True)
        self.df = np.sqrt(np.einsum("ij,ij->i", self.f_tilde, self.f_tilde, dtype=np.float64))
        hxx = np.einsum("ij,ij->i", self.fx, self.fx, dtype=np.float64)
        hxy = np.einsum("ij,ij->i", self.fx, self.fy, dtype=np.float64)
        hyy = np.einsum("ij,ij->i", self.fy, self.fy, dtype=np.float64)
        det = hxx * hyy - hxy**2
        # a block without texture (flat, or gradients along one direction only) cannot be solved
        self.textured = (self.df > 1e-3) & (det > 1e-6 * np.maximum(hxx * hyy, 1e-30))
        det = np.where(self.textured, det, 1.0)
        self.ixx, self.ixy, self.iyy = hyy / det, -hxy / det, hxx / det
        self.grad_sq = np.column_stack([hxx, hyy])  # sum of squared x and y gradients (gray^2)
        # One product per step gives every sum it needs (see :meth:`step`): with e = f~ - (df/dg) g~,
        # du = H^-1 [fx.e, fy.e] = H^-1 [fx.f~, fy.f~] - (df/dg) H^-1 [fx.g~, fy.g~], and x.g~ = (x - mean x).g.
        # Rows: 1 (sum g), f~ - mean (f~.g~), then H^-1 applied to the centred gradients (the step's g~ part).
        fx0 = self.fx.astype(np.float64)
        fy0 = self.fy.astype(np.float64)
        fx0 -= fx0.mean(axis=1, keepdims=True)
        fy0 -= fy0.mean(axis=1, keepdims=True)
        ft0 = self.f_tilde.astype(np.float64)
        ft0 -= ft0.mean(axis=1, keepdims=True)
        ixx, ixy, iyy = self.ixx[:, None], self.ixy[:, None], self.iyy[:, None]
        self._proj = np.stack([np.ones_like(ft0), ft0, ixx * fx0 + ixy * fy0, ixy * fx0 + iyy * fy0], axis=1)
        bx0 = np.einsum("ij,ij->i", self.fx, self.f_tilde, dtype=np.float64)
        by0 = np.einsum("ij,ij->i", self.fy, self.f_tilde, dtype=np.float64)
        # H^-1 [fx.f~, fy.f~]
        self._du_f = np.column_stack([self.ixx * bx0 + self.ixy * by0, self.ixy * bx0 + self.iyy * by0])
        # block 0's constants as Python floats, for one block's compiled IC-GN (vibro_dic.kernels.refine_box)
        self._one = (float(self.df[0]), float(self._du_f[0, 0]), float(self._du_f[0, 1]))

    def __len__(self) -> int:
        return len(self.corners)

    def inside(self, u: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """Mask of blocks whose interpolation support, displaced by u (N, 2) px, is inside the image."""
        return support_inside(self.corners[:, 0] + u[:, 0], self.corners[:, 1] + u[:, 1],
                              self.size, self.taps, shape)

    def sample(self, image: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(N, h, w) samples of all blocks displaced by u (N, 2) px (supports must be inside)."""
        return sample_blocks(image, self.corners[:, 0] + u[:, 0], self.corners[:, 1] + u[:, 1], self.size, self.taps)

    def step(self, g: np.ndarray, idx: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One Gauss-Newton step for blocks ``idx`` given their samples ``g`` (m, h*w) at the current u.

        Returns (du (m, 2) px to ADD to u, zncc (m,) at the current u, ok (m,) bool:
        the sample has texture). ``idx`` None means all blocks.
        """
        sl = slice(None) if idx is None else idx
        g = g.reshape(len(g), -1).astype(np.float64)
        # In float64, so that dg^2 = g.g - (sum g)^2 / n loses nothing; rows of _proj: see __init__
        sums = np.matmul(self._proj[sl], g[:, :, None])[..., 0]  # (m, 4): sum g, f~.g~, H^-1 [fx.g~, fy.g~]
        dg2 = np.einsum("ij,ij->i", g, g) - sums[:, 0] * sums[:, 0] / g.shape[1]
        ok = dg2 > 1e-6
        dg = np.sqrt(np.where(ok, dg2, 1.0))
        df = self.df[sl]
        zncc = np.where(ok, sums[:, 1] / (df * dg), np.nan)
        du = self._du_f[sl] - (df / dg)[:, None] * sums[:, 2:]
        du[~ok] = 0.0
        return du, zncc, ok

    def refine(self, image: np.ndarray, u0: np.ndarray, active: np.ndarray | None = None) -> IcgnResult:
        """Refine displacements from the start ``u0`` (N, 2) px on ``image`` (2-D float32).

        A block whose support leaves the image, that moves more than ``max_move_px``
        from its start, or does not converge in ``max_iter`` iterations comes back
        with converged=False.
        """
        n = len(self.corners)
        u0 = np.asarray(u0, dtype=np.float64).reshape(n, 2)
        u = u0.copy()
        zncc = np.full(n, np.nan)
        converged = np.zeros(n, dtype=bool)
        live = self.textured.copy() if active is None else (self.textured & active)
        it = 0
        for it in range(1, self.max_iter + 1):
            live &= self.inside(u, image.shape)
            live &= np.all(np.abs(u - u0) <= self.max_move_px, axis=1)
            idx = np.flatnonzero(live)
            if idx.size == 0:
                break
            g = sample_blocks(image, self.corners[idx, 0] + u[idx, 0], self.corners[idx, 1] + u[idx, 1],
                              self.size, self.taps)
            du, z, ok = self.step(g, idx)
            zncc[idx] = z
            u[idx] += du
            done = ok & (np.einsum("ij,ij->i", du, du) <= self.tol_px**2)
            converged[idx[done]] = True
            live[idx[done | ~ok]] = False
        return IcgnResult(u=u, zncc=zncc, converged=converged, iterations=it)
