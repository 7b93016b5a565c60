"""Frame-by-frame DIC tracking of the ball and the structure (rigid translations).

Pipeline for each mesh (ball, structure) and each frame:

1. **Prediction**: the mesh displacement is extrapolated from the last good frames
   (constant acceleration from three, constant velocity from two; frame indices are
   used, so dropped frames are handled). The structure, which the shaker drives
   sinusoidally, is extrapolated instead by the sine at the drive frequency (and an offset)
   through its last three frames when the tracker is given that frequency
   (``structure_drive_cycles_per_frame``; :meth:`DicTracker.for_rig` takes it from rig.yaml):
   exact for the driven motion however far apart those frames are, where a parabola through
   frames 5-10 ms apart (a live tracker that fell behind and dropped images) misses by pixels.
2'. **Refine from the prediction** (``method="icgn"``, three frames of history): the bounding box is
   refined by IC-GN straight from the predicted displacement, without a search. In free flight a
   quadratic prediction is exact to the noise, so this converges in 2-3 steps. It is kept only if it
   converged within :data:`PREDICTION_MAX_ITER` steps, within :data:`PREDICTION_TRUST_PX` of the
   prediction (inside the Gauss-Newton basin of speckle, so the peak reached is the one the search would
   find), with ZNCC >= ``zncc_min``, and the mesh is not lost (step 7). Otherwise (an impact, a reseed,
   a lost frame before) the frame goes through steps 2-3 as below. The search costs about as much as
   the rest of a frame's DIC.
2. **Integer search** by ZNCC (paper Eq. 1, ``cv2.matchTemplate`` TM_CCOEFF_NORMED) of the
   mesh's bounding box (the union of its subsets, frame 0) in a window of +-``search_px`` (default 4)
   around the prediction. If the peak is below ``zncc_min`` or on the window's border,
   the window is widened to cover the last good position +- (2 x fastest recent speed x
   frames elapsed + search_px) (a reversal at an impact; with one frame of history there is no speed, and
   this step is left out); failing that the whole image is searched, coarse to fine
   (:func:`vibro_dic.search.whole_image_search`: half resolution first).
3. **Sub-pixel**:
   - ``method="icgn"``: translation IC-GN (ZNSSD, Keys cubic interpolation; see
     :mod:`vibro_dic.icgn`) first on the whole bounding box, then one Gauss-Newton step
     per subset from there (per-point estimates; a point whose step exceeds
     ``tol_px`` is iterated on its own until it converges).
   - ``method="parabolic"`` (baseline): per subset, ZNCC search +-2 px around the mesh's
     integer displacement and a 1-D parabola through the peak and its neighbours in x
     and in y.
4. **Robust rigid displacement**. A point is kept when (a) it converged (IC-GN step below
   tol within max_iter, or a parabolic peak not on its window's border), (b) its ZNCC is
   >= ``zncc_min``, and (c) both displacement components lie within
   max(``outlier_k`` x 1.4826 x MAD, ``outlier_floor_px``) of the median over the points
   passing (a) and (b). The mesh displacement is the mean of the kept points; for the ball, the
   rigid fit's translation of the mesh centroid (the mean minus the rotation's share at the points'
   mean lever arm, step 5), so that a spinning ball's rotation does not leak into its translation.
5. **In-plane rotation** (:mod:`vibro_dic.rotation`): least-squares rigid rotation of the kept points'
   displacements about the mesh centroid, each point's lever arm corrected for what a translation-only
   subset measures of a rotation (its gradient-weighted centre); small angle. Positive counter-clockwise
   as the camera sees the image; with its 1-sigma noise from the residuals about the rigid fit.
6. **Re-seed**: the prediction history (step 1) never crosses a multiple of ``reseed_every`` frames
   (:data:`RESEED_EVERY_FRAMES`, 100): at the first frame of each segment ``[j*K, (j+1)*K)`` of frame
   indices, both meshes start again as at frame 1 (no prediction: the search of step 2 from the frame-0
   position, widened to the whole image when the body has moved). The segments are a fixed property of the
   tracking, whoever runs it: one process (:func:`track_recording`) or chunks of whole segments on Dask
   workers (:mod:`vibro_dic.chunked`) give identical rows, whatever the number of workers.
7. **Lost**: no ZNCC peak >= ``zncc_min`` anywhere, the bounding box leaving the image, or
   fewer than ``min_valid_fraction`` of the points kept. A lost mesh reports NaN
   displacement and 0 valid points; it is never extrapolated. The frame is flagged lost
   if either mesh is lost or the image is missing (the other mesh keeps its value).
8. **Lens distortion** (rig.yaml ``camera.calibration``, a ROS camera_info; :meth:`DicTracker.use_calibration`):
   after steps 1-7, which work in the camera's own pixels, each kept subset's centre (where its translation samples
   the displacement field: its gradient-weighted centre, :func:`vibro_dic.rotation.effective_centres`) now and in
   the reference is undistorted (:func:`vibro_io.camera_calibration.undistort_px`: pixels of the same focal length)
   and the mesh's displacement is corrected by the mean of (undistorted translation - measured translation) over its
   kept points (with the geometric centres ~1 um of the lens's changing magnification was left in the track, and a
   flight's apparent gravity 0.17 % low: a 3.4 deg tilt claimed on a rig at 0 deg); an outline's circle is
   refitted through its undistorted edge points. One vectorised OpenCV call per frame on the subset centres (edge
   points); the compiled kernels are untouched. Without a calibration nothing
   of this runs.

Output conventions (:class:`vibro_io.dictrack.FrameTrack`): displacement since frame 0 in
mm, POSITIVE UP; image rows grow downward, so ``up_mm = -u_y_px * mm_per_px``.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Iterable, Iterator

import numpy as np

from vibro_io.camera_calibration import CameraCalibration, calibration_of_rig, undistort_points
from vibro_io.dictrack import FrameTrack
from vibro_io.frames import Frame
from vibro_io.rig import DicConfig, Roi, check_rois_in_image
from vibro_model.errors import FrameError, RecordingError

from . import kernels
from .ball_method import BallMethodChoice, resolve_ball_method
from .icgn import IcgnBlocks, extract_blocks
from .interp import CUBIC_IN_T, KERNEL_TAPS, patch_margin
from .mesh import mesh_points
from .methods import METHODS
from .outline import OutlineResult, OutlineTracker, edge_points, fit_circle
from .quality import TrackQuality
from .rotation import MIN_ARM_SPREAD_PX2, effective_centres, rotation_lever_arms
from .search import SearchResult, half_resolution, whole_image_search, zncc_search
from .speckle import speckle_pattern
from .texture import DEFAULT_MAX_SUBSET_SIGMA_PX, TextureReport, check_texture

log = logging.getLogger(__name__)

MIN_SUBSET_STD = 2.0  # gray levels: below this a subset holds no usable pattern
# The bounding-box IC-GN stops at a finer step than the subsets' tol_px, so that the one
# per-subset step that follows is dominated by the subset's own (noise) deviation.
BOX_TOL_PX = 0.005
#: a sinusoidal prediction (step 1) whose weights on the three history frames sum (in absolute value) beyond
#: this amplifies their noise too much (history frames nearly a whole drive period apart); the parabola is used
MAX_SINE_WEIGHT_SUM = 100.0
#: the box refined from the motion prediction (step 2') is kept only within this distance of it (px per axis):
#: well inside the +-1-2 px Gauss-Newton basin of speckle, so the peak reached is the one a search would find
PREDICTION_TRUST_PX = 0.5
#: ... and only when it converged within this many Gauss-Newton steps (from a prediction that close it takes 2-3;
#: a wrong prediction, at an impact, is given up early and the frame searched)
PREDICTION_MAX_ITER = 4
#: frames per tracking segment: the motion prediction restarts at every multiple of this frame index
#: (module doc, step 6); chunked tracking splits a recording only there
RESEED_EVERY_FRAMES = 100


@dataclass(kw_only=True)
class MeshResult:
    """Outcome for one mesh in one frame (pixels, image axes: x = column, y = row down)."""

    name: str
    u_px: np.ndarray  # (2,) mean displacement (x, y) px since frame 0; NaN when lost
    valid: int
    zncc: float  # mean ZNCC of the kept points (NaN when none)
    lost: bool
    reason: str = ""
    point_u_px: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    point_valid: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    point_zncc: np.ndarray = field(default_factory=lambda: np.empty(0))
    rot_rad: float = math.nan      # in-plane rotation since frame 0 (rad, + counter-clockwise on screen)
    rot_std_rad: float = math.nan  # its 1-sigma noise (rad); NaN when fewer than 2 points or lost


@dataclass(frozen=True, kw_only=True)
class TrackingConfig:
    """How a mesh is tracked (module doc): the options :class:`DicTracker` takes by keyword.

    Attributes
    ----------
    method : str
        Sub-pixel method: "icgn" (default) or "parabolic" (baseline).
    zncc_min : float
        Lowest ZNCC of a search peak and of a kept point, in (0, 1).
    min_valid_fraction : float
        Fraction of a mesh's points that must be kept, in (0, 1]; fewer: the mesh is lost.
    search_px : int
        Half-width (px) of the first integer-search window around the prediction.
    taps : int
        Interpolation kernel taps (:data:`vibro_dic.interp.KERNEL_TAPS`).
    tol_px : float
        IC-GN convergence step of a subset (px).
    outlier_k : float
        Outlier limit in robust standard deviations (1.4826 x MAD) from the median displacement.
    outlier_floor_px : float
        Smallest outlier limit (px).
    """

    method: str = "icgn"
    zncc_min: float = 0.6
    min_valid_fraction: float = 0.5
    search_px: int = 4
    taps: int = 6
    tol_px: float = 0.02
    outlier_k: float = 3.0
    outlier_floor_px: float = 0.1


DEFAULT_TRACKING = TrackingConfig()


class MeshTracker:
    """Tracks one rigid mesh of subsets against the reference image (see module doc)."""

    def __init__(self, name: str, reference: np.ndarray, roi: Roi, subset_px: int, step_px: int, *,
                 tracking: TrackingConfig = DEFAULT_TRACKING, rotation_corrected: bool = False,
                 drive_rad_per_frame: float | None = None):
        method, taps, tol_px = tracking.method, tracking.taps, tracking.tol_px
        self.name = name
        self.drive_rad_per_frame = drive_rad_per_frame  # sinusoidal prediction (step 1) when given
        self.rotation_corrected = rotation_corrected
        self.method = method
        self.subset_px = subset_px
        self.zncc_min = tracking.zncc_min
        self.search_px = tracking.search_px
        self.outlier_k = tracking.outlier_k
        self.outlier_floor_px = tracking.outlier_floor_px
        self.points = mesh_points(roi, subset_px, step_px)  # (N, 2) centres
        n = len(self.points)
        self.min_valid = max(1, math.ceil(tracking.min_valid_fraction * n - 1e-9))
        h = subset_px // 2
        self.corners = self.points - h  # top-left pixels of the subsets
        x0, y0 = self.corners.min(axis=0)
        x1, y1 = self.corners.max(axis=0) + subset_px
        self.box_corner = np.array([x0, y0], dtype=float)
        self.box_size = (int(y1 - y0), int(x1 - x0))  # (h, w) of the union of the subsets
        self.template = extract_blocks(reference, [x0], [y0], self.box_size)[0]
        self._half_template = half_resolution(self.template)  # the whole-image search's coarse level
        self.box = IcgnBlocks(reference, self.box_corner[None], self.box_size, taps=taps, tol_px=BOX_TOL_PX,
                              max_move_px=2.0)
        self.subsets = IcgnBlocks(reference, self.corners, (subset_px, subset_px), taps=taps, tol_px=tol_px,
                                  max_move_px=2.0)
        self.offsets = (self.corners - self.box_corner).astype(np.intp)  # subset corners inside the box
        self.lever_arms = rotation_lever_arms(self.subsets, self.points, subset_px)  # (N, 2) px per rad
        self.effective_points = effective_centres(self.subsets, self.points, subset_px)  # (N, 2) where u is measured
        # the compiled kernels' inputs (vibro_dic.kernels) beside the IC-GN constants: interpolation cubics, scratch
        self._cubic = np.ascontiguousarray(CUBIC_IN_T[taps], dtype=np.float64)
        self._box_g = np.empty(self.box_size, dtype=np.float32)  # the box's samples at its last u
        self._box_tmp = np.empty((self.box_size[0] + taps - 1, self.box_size[1]), dtype=np.float32)
        if method == "parabolic":
            self.subset_templates = extract_blocks(reference, self.corners[:, 0], self.corners[:, 1],
                                                   (subset_px, subset_px))
        self.history: deque[tuple[int, np.ndarray]] = deque(maxlen=3)
        self._weights: dict[tuple, np.ndarray] = {}  # prediction weights by history pattern (predict)
        self.n_widened = 0  # frames whose first search window missed (statistics)
        self.n_global = 0  # frames that needed the whole-image search
        self.n_predicted = 0  # frames refined straight from the prediction, with no search (step 2')
        # bad input: a ROI without speckle (flat, saturated) cannot be tracked at all
        std = self.subsets.df / math.sqrt(subset_px * subset_px)  # gray-level std of each subset
        self.subsets.textured &= std >= MIN_SUBSET_STD  # such subsets are never used
        textured = int(np.count_nonzero(self.subsets.textured))
        if textured < self.min_valid:
            raise RecordingError(
                f"dic.{name}_roi {roi.as_list()}: only {textured} of {n} subsets have speckle texture in "
                f"frame 0 (gray-level std >= {MIN_SUBSET_STD:g}); need {self.min_valid}: put the ROI on the pattern")

    def reseed(self) -> None:
        """Forget the motion history: the next frame is searched as if it were the first after frame 0."""
        self.history.clear()

    # --- prediction and integer search ---------------------------------------------------------
    def predict(self, k: int) -> np.ndarray:
        """Predicted displacement (x, y) px at frame k: quadratic (3 frames), linear (2) or last (1) fit, or the
        drive's sine through 3 frames (module doc, step 1)."""
        if not self.history:
            return np.zeros(2)
        if len(self.history) == 1:
            return self.history[0][1].copy()
        k_last = self.history[-1][0]
        pattern = (tuple(kh - k_last for kh, _ in self.history), k - k_last)  # frame offsets: weights depend on these
        weights = self._weights.get(pattern)
        if weights is None:
            weights = self._prediction_weights(*pattern)
            if len(self._weights) >= 256:  # a tracker that keeps dropping frames meets many patterns
                self._weights.clear()
            self._weights[pattern] = weights
        return weights @ np.array([u for _, u in self.history])

    def _prediction_weights(self, offsets: tuple[int, ...], target: int) -> np.ndarray:
        """Weights of the history frames (at ``offsets`` from the last, in frames) giving the prediction at
        ``target``: the drive's sine when it is given and determined by 3 frames, else Lagrange extrapolation
        (exact for constant velocity or acceleration)."""
        if self.drive_rad_per_frame is not None and len(offsets) == 3:
            sine = self._sine_weights(offsets, target)
            if sine is not None:
                return sine
        weights = np.ones(len(offsets))
        for i, ki in enumerate(offsets):
            for j, kj in enumerate(offsets):
                if j != i:
                    weights[i] *= (target - kj) / (ki - kj)
        return weights

    def _sine_weights(self, offsets: tuple[int, ...], target: int) -> np.ndarray | None:
        """Weights for u = a cos(w j) + b sin(w j) + c through the frames at ``offsets`` (j in frames), at
        ``target``; None when those frames do not determine it (two of them a whole number of drive periods
        apart, after a long loss)."""
        w = self.drive_rad_per_frame
        basis = np.array([[math.cos(w * j), math.sin(w * j), 1.0] for j in offsets])
        try:
            weights = np.linalg.solve(basis.T, [math.cos(w * target), math.sin(w * target), 1.0])
        except np.linalg.LinAlgError:
            return None
        # a near-singular fit amplifies the history's noise without bound: then the parabola predicts
        if not np.sum(np.abs(weights)) <= MAX_SINE_WEIGHT_SUM:
            return None
        return weights

    def search(self, image: np.ndarray, k: int) -> SearchResult | None:
        def good(res: SearchResult | None) -> bool:
            return res is not None and not res.on_border and res.zncc >= self.zncc_min

        r = self.search_px
        pred = self.predict(k)
        cx, cy = (self.box_corner + np.rint(pred)).astype(int)
        res = zncc_search(image, self.template, cx - r, cx + r, cy - r, cy + r)
        if good(res):
            return res
        self.n_widened += 1
        if len(self.history) >= 2:  # one frame of history has no speed: the widened window would be this one
            k_last, u_last = self.history[-1]
            # fastest recent speed (px/frame) per axis; x2 covers a reversal (impact) since then
            speed = np.zeros(2)
            for (k0, u0), (k1, u1) in zip(list(self.history)[:-1], list(self.history)[1:]):
                speed = np.maximum(speed, np.abs(u1 - u0) / (k1 - k0))
            ext = 2.0 * speed * max(k - k_last, 1) + r
            lx, ly = self.box_corner + u_last
            x_lo, x_hi = int(min(lx - ext[0], cx - r)), int(math.ceil(max(lx + ext[0], cx + r)))
            y_lo, y_hi = int(min(ly - ext[1], cy - r)), int(math.ceil(max(ly + ext[1], cy + r)))
            res2 = zncc_search(image, self.template, x_lo, x_hi, y_lo, y_hi)
            if good(res2):
                return res2
        self.n_global += 1
        res3 = whole_image_search(image, self.template, self._half_template, self.zncc_min)
        if res3 is not None and res3.zncc >= self.zncc_min:
            return res3
        return None

    # --- sub-pixel ---------------------------------------------------------------------------------
    def _refine_box(self, image: np.ndarray, u_start: np.ndarray, *, max_move_px: float | None = None,
                    max_iter: int | None = None) -> tuple[np.ndarray, np.ndarray, float] | None:
        """IC-GN of the whole bounding box from ``u_start`` (2,) px to a step below BOX_TOL_PX: (u px, the box
        sampled at u, its ZNCC), or None when it leaves the image, moves more than ``max_move_px`` (default the
        box's) from the start, or has not converged in ``max_iter`` iterations (default the box's).
        One compiled call (:func:`vibro_dic.kernels.refine_box`); the samples returned are overwritten by the
        next call."""
        box = self.box
        df, du_fx, du_fy = box._one
        code, ux, uy, zncc = kernels.refine_box(
            image, float(self.box_corner[0]), float(self.box_corner[1]), float(u_start[0]), float(u_start[1]),
            self.box._proj[0], df, du_fx, du_fy, self._cubic,
            float(box.max_move_px if max_move_px is None else max_move_px),
            int(box.max_iter if max_iter is None else max_iter), float(box.tol_px), self._box_g, self._box_tmp)
        if code != kernels.CONVERGED:
            return None
        return np.array([ux, uy]), self._box_g, zncc  # sampled at u; the per-subset steps start from here

    def _subset_points(self, image: np.ndarray, u_box: np.ndarray, g_box: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One Gauss-Newton step per subset from the converged box (its samples ``g_box`` at ``u_box``);
        points whose step exceeds tol are iterated on their own."""
        m = len(self.points)
        du, zncc, ok = np.empty((m, 2)), np.empty(m), np.empty(m, dtype=bool)
        kernels.subset_steps(g_box, self.offsets, self.subsets._proj, self.subsets.df, self.subsets._du_f,
                             du, zncc, ok)
        pu = u_box + du
        big = np.einsum("ij,ij->i", du, du) > self.subsets.tol_px ** 2
        converged = ok & ~big & self.subsets.textured
        if np.any(big & ok):
            again = self.subsets.refine(image, pu, active=big & ok)
            pu[big] = again.u[big]
            zncc[big] = again.zncc[big]
            converged |= again.converged & big
        return pu, zncc, converged

    def _icgn_points(self, image: np.ndarray, u_start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """IC-GN on the bounding box to convergence, then one Gauss-Newton step per subset from the
        box's last sample; every subset on its own from ``u_start`` when the box does not converge."""
        box = self._refine_box(image, u_start)
        if box is not None:
            return self._subset_points(image, box[0], box[1])
        res = self.subsets.refine(image, np.repeat(u_start[None], len(self.points), axis=0))
        return res.u, res.zncc, res.converged

    def _track_predicted(self, image: np.ndarray, k: int) -> MeshResult | None:
        """Step 2' (IC-GN only): the box refined straight from the prediction, with no integer search.

        Kept only when the prediction is quadratic (three frames of history), the box converges within
        PREDICTION_TRUST_PX of it (far inside the Gauss-Newton basin of a speckle pattern, so no other
        correlation peak can be reached) with ZNCC >= ``zncc_min``, and the mesh is not lost; otherwise
        None, and the frame goes through the search (an impact, a reseed, a lost frame)."""
        if self.method != "icgn" or len(self.history) < 3:
            return None
        pred = self.predict(k)  # a prediction outside the image: _refine_box gives None (its first check)
        box = self._refine_box(image, pred, max_move_px=PREDICTION_TRUST_PX, max_iter=PREDICTION_MAX_ITER)
        if box is None:
            return None
        u_box, g_box, zncc_box = box
        if not zncc_box >= self.zncc_min:
            return None
        out = self._combine(*self._subset_points(image, u_box, g_box))
        if out.lost:
            return None
        self.n_predicted += 1
        return out

    def _parabolic_points(self, image: np.ndarray, d_int: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(self.points)
        u = np.full((n, 2), np.nan)
        zncc = np.full(n, np.nan)
        ok = np.zeros(n, dtype=bool)
        for i in range(n):
            cx, cy = (self.corners[i] + d_int).astype(int)
            res = zncc_search(image, self.subset_templates[i], cx - 2, cx + 2, cy - 2, cy + 2)
            if res is None:
                continue
            u[i] = (res.x - self.corners[i, 0] + res.sub_dx, res.y - self.corners[i, 1] + res.sub_dy)
            zncc[i] = res.zncc
            ok[i] = not res.on_border
        return u, zncc, ok

    # --- one frame -------------------------------------------------------------------------------
    def lost(self, reason: str) -> MeshResult:
        return MeshResult(name=self.name, u_px=np.full(2, np.nan), valid=0, zncc=float("nan"), lost=True, reason=reason)

    def track(self, image: np.ndarray, k: int) -> MeshResult:
        """Track this mesh in ``image`` (2-D float32) of frame index ``k``."""
        out = self._track_predicted(image, k)
        if out is not None:
            self.history.append((k, out.u_px.copy()))
            return out
        res = self.search(image, k)
        if res is None:
            pred = self.predict(k)
            if self.history and not self.box.inside(pred[None], image.shape)[0]:
                return self.lost(f"{self.name}: ROI leaves the image (predicted displacement "
                                 f"{pred.round(1).tolist()} px) and no ZNCC peak >= {self.zncc_min:g} inside")
            return self.lost(f"{self.name}: no ZNCC peak >= {self.zncc_min:g} in the image")
        d_int = np.array([res.x, res.y], dtype=float) - self.box_corner
        u_start = d_int + (res.sub_dx, res.sub_dy)
        if not self.box.inside(u_start[None], image.shape)[0]:
            return self.lost(f"{self.name}: ROI leaves the image (displacement {u_start.round(1).tolist()} px)")
        if self.method == "icgn":
            u, zncc, conv = self._icgn_points(image, u_start)
        else:
            u, zncc, conv = self._parabolic_points(image, d_int)
        out = self._combine(u, zncc, conv)
        if not out.lost:
            self.history.append((k, out.u_px.copy()))
        return out

    def _combine(self, u: np.ndarray, zncc: np.ndarray, conv: np.ndarray) -> MeshResult:
        """The mesh's result from its points (:func:`vibro_dic.kernels.combine_points`: valid points, outliers
        dropped, the rigid fit with rotation)."""
        n = len(u)
        valid = np.empty(n, dtype=bool)
        nv, ux, uy, zncc_mean, theta, theta_std, _, arm_x, arm_y = kernels.combine_points(
            np.ascontiguousarray(u, dtype=np.float64), np.ascontiguousarray(zncc, dtype=np.float64),
            np.ascontiguousarray(conv, dtype=np.bool_), self.zncc_min, self.outlier_k, self.outlier_floor_px,
            self.lever_arms, MIN_ARM_SPREAD_PX2, valid)
        if nv < self.min_valid:
            r = self.lost(f"{self.name}: too few valid points ({nv} of {n}, need {self.min_valid})")
            r.point_u_px, r.point_valid, r.point_zncc = u, valid, zncc
            return r
        mean_u = np.array([ux, uy])
        if self.rotation_corrected and math.isfinite(theta):
            # the mean of the points' estimates is the displacement of their mean lever arm's point (their
            # gradient-weighted centre, ~1-2 px off the centroid): remove the rotation's share there
            mean_u -= theta * np.array([arm_x, arm_y])
        return MeshResult(name=self.name, u_px=mean_u, valid=nv, zncc=zncc_mean, lost=False, reason="",
                          point_u_px=u, point_valid=valid, point_zncc=zncc, rot_rad=theta, rot_std_rad=theta_std)


def _circle_centre(points: np.ndarray, radius_px: float) -> np.ndarray | None:
    """(2,) px: the centre of the circle through ``points`` (K, 2) (the outline's robust geometric fit, equal
    weights), from their mean and ``radius_px``; None when it cannot be fitted."""
    n = len(points)
    fit = fit_circle(points, np.ones(n), np.ones(n, dtype=bool), points.mean(axis=0), radius_px)
    return None if fit is None else fit.centre


def compile_kernels() -> float:
    """Compile the tracker's numba kernels (:mod:`vibro_dic.kernels`) for the types it passes, or load them from
    numba's cache beside the module: a mesh on a synthetic speckle tracked through every per-frame path (search,
    prediction). ``make setup`` runs it once, so that test processes and nodes load the machine code instead
    of each compiling it (~5 s). Returns the seconds it took."""
    t0 = time.perf_counter()
    pattern = speckle_pattern((80, 80), seed=0)
    mesh = MeshTracker("ball", pattern.render().astype(np.float32), Roi(20, 20, 40, 40), 31, 9)
    for k in range(5):
        mesh.track(pattern.render(0.1 * k, -0.2 * k).astype(np.float32), k)
    return time.perf_counter() - t0


def _check_tracker_inputs(ref: np.ndarray, mm_per_px: float, tracking: TrackingConfig, reseed_every: int,
                          drive: float | None) -> None:
    """Raise for an unusable tracker option or reference image (the :class:`DicTracker` arguments)."""
    if tracking.method not in METHODS:
        raise RecordingError(f"DIC method must be one of {', '.join(METHODS)}, got {tracking.method!r}")
    if ref.ndim != 2 or ref.size == 0:
        raise FrameError(f"reference image must be a 2-D grayscale array, got shape {ref.shape}")
    if not (math.isfinite(mm_per_px) and mm_per_px > 0):
        raise RecordingError(f"camera.mm_per_px must be a positive number, got {mm_per_px!r}")
    if not 0.0 < tracking.zncc_min < 1.0:
        raise RecordingError(f"zncc_min must be in (0, 1), got {tracking.zncc_min!r}")
    if not 0.0 < tracking.min_valid_fraction <= 1.0:
        raise RecordingError(f"min_valid_fraction must be in (0, 1], got {tracking.min_valid_fraction!r}")
    if tracking.taps not in KERNEL_TAPS:
        raise RecordingError(f"interpolation taps must be one of {KERNEL_TAPS}, got {tracking.taps!r}")
    if tracking.search_px < 1:
        raise RecordingError(f"search_px must be >= 1, got {tracking.search_px!r}")
    if isinstance(reseed_every, bool) or not isinstance(reseed_every, int) or reseed_every < 1:
        raise RecordingError(f"reseed_every must be a positive number of frames, got {reseed_every!r}")
    if drive is not None and not (isinstance(drive, (int, float)) and 0.0 < drive < 0.5):
        raise RecordingError(f"structure_drive_cycles_per_frame (excitation frequency / camera fps) must be in "
                             f"(0, 0.5), below the Nyquist limit; got {drive!r}")


def _check_rois_fit(shape: tuple[int, ...], dic_config: DicConfig, taps: int) -> None:
    """Raise unless both ROIs (px) lie in the reference image of ``shape`` with the interpolation's margin."""
    rows, cols = shape
    before, after = patch_margin(taps)
    for name in ("ball_roi", "structure_roi"):
        roi: Roi = getattr(dic_config, name)
        if roi.x < 0 or roi.y < 0 or roi.x + roi.w > cols or roi.y + roi.h > rows:
            raise RecordingError(f"dic.{name} {roi.as_list()} (x, y, w, h) goes outside the "
                                 f"{cols}x{rows} px reference image")
        if roi.x < before or roi.y < before or roi.x + roi.w > cols - after or roi.y + roi.h > rows - after:
            raise RecordingError(f"dic.{name} {roi.as_list()} (x, y, w, h) must keep {before} px from the "
                                 f"left/top and {after} px from the right/bottom image border (sub-pixel "
                                 f"interpolation support); the image is {cols}x{rows} px")


class DicTracker:
    """Streaming DIC tracker of ball and structure against ``reference_image`` (frame 0).

    The ball is a DIC mesh, or (rig.yaml ``dic.ball_method: outline``) a plain ball tracked by its outline
    (:class:`vibro_dic.outline.OutlineTracker`: same results, rotation NaN = not measured); the structure is
    always a DIC mesh.

    ``dic_config`` gives subset size, mesh step and the two ROIs (px, frame 0);
    ``mm_per_px`` converts to mm. ``tracking`` (:class:`TrackingConfig`) sets how the meshes are tracked; its
    fields may also be given by keyword (``method="parabolic"``, ``zncc_min=0.7``, ...), overriding it.
    Call :meth:`track` once per frame, in order; it keeps the motion prediction within a segment of
    ``reseed_every`` frame indices (module doc, step 6).
    """

    def __init__(self, reference_image: np.ndarray, dic_config: DicConfig, mm_per_px: float, *,
                 tracking: TrackingConfig = DEFAULT_TRACKING, reseed_every: int = RESEED_EVERY_FRAMES,
                 structure_drive_cycles_per_frame: float | None = None, **tracking_options):
        tracking = replace(tracking, **tracking_options) if tracking_options else tracking
        ref = np.asarray(reference_image)
        drive = structure_drive_cycles_per_frame
        _check_tracker_inputs(ref, mm_per_px, tracking, reseed_every, drive)
        _check_rois_fit(ref.shape, dic_config, tracking.taps)
        self.reseed_every = reseed_every
        self._segment: int | None = None  # segment (index // reseed_every) of the last frame tracked
        self.shape = ref.shape
        self.method = tracking.method
        self.mm_per_px = float(mm_per_px)
        ref32 = ref.astype(np.float32)
        if dic_config.ball_method == "outline":  # a plain ball by its outline (vibro_dic.outline)
            self.ball = OutlineTracker("ball", ref32, dic_config.ball_roi,
                                       min_valid_fraction=tracking.min_valid_fraction)
        else:
            self.ball = MeshTracker("ball", ref32, dic_config.ball_roi, dic_config.subset_px,
                                    dic_config.mesh_step_px, tracking=tracking, rotation_corrected=True)
        self.structure = MeshTracker("structure", ref32, dic_config.structure_roi, dic_config.subset_px,
                                     dic_config.mesh_step_px, tracking=tracking,
                                     drive_rad_per_frame=None if drive is None else 2.0 * math.pi * drive)
        self.last_results: dict[str, MeshResult] = {}
        self.calibration: CameraCalibration | None = None
        self._reference_undistorted: dict[str, np.ndarray] = {}

    @classmethod
    def for_rig(cls, reference_image: np.ndarray, rig, **kwargs) -> "DicTracker":
        """The tracker of a rig (:class:`vibro_io.rig.Rig`): its DIC configuration and scale, and the structure
        predicted as a sine at the excitation frequency (step 1). ``kwargs`` as for the constructor. The ball is
        tracked as rig.yaml ``dic.ball_method`` names, else as the texture of ``reference_image`` chooses
        (:func:`vibro_dic.ball_method.choose_ball_method`)."""
        cycles = rig.excitation.frequency_hz / rig.camera.fps
        dic = resolve_ball_method(reference_image, rig.dic).dic
        tracker = cls(reference_image, dic, rig.camera.mm_per_px,
                      structure_drive_cycles_per_frame=cycles if cycles < 0.5 else None, **kwargs)
        shape = np.asarray(reference_image).shape
        tracker.use_calibration(calibration_of_rig(rig, (shape[1], shape[0])))  # rig.yaml camera.calibration
        return tracker

    def use_calibration(self, calibration: CameraCalibration | None) -> None:
        """Undistort the tracked positions with ``calibration`` (None: no more; module doc, step 8). Raises
        :class:`vibro_io.camera_calibration.CameraInfoError` when it was made at another image size."""
        self._reference_undistorted = {}
        self.calibration = calibration
        if calibration is None:
            return
        calibration.check_image_size(self.shape[1], self.shape[0], "the reference image's")
        for mesh in (self.ball, self.structure):
            if isinstance(mesh, OutlineTracker):  # the centre of the undistorted outline
                ref = _circle_centre(undistort_points(calibration, edge_points(mesh.reference_fit)), mesh.radius0)
                self._reference_undistorted[mesh.name] = mesh.centre0 if ref is None else ref
            else:
                self._reference_undistorted[mesh.name] = undistort_points(calibration, mesh.effective_points)

    def _undistort(self, results: tuple[MeshResult, MeshResult]) -> None:
        """The (ball, structure) results' ``u_px`` replaced by their displacement in the undistorted image (module
        doc, step 8). A mesh's: corrected by the mean over its kept subsets of (undistorted centre now -
        undistorted centre in the reference - measured displacement), each subset's centre where its translation
        samples the displacement field (its gradient-weighted centre, :func:`vibro_dic.rotation.effective_centres`:
        a lens's magnification changes across the image, and the geometric centre left ~1 um of that in the
        track); the rotation's share stays as measured. An
        outline's: the circle through its undistorted edge points, less the reference's (a lens turns the ball's
        circle into an oval whose fitted centre is not the distorted centre: a barrel lens moves it by
        3 k1 y R^2 / f^2 at y from the principal point). One vectorised call for every point of both bodies."""
        bodies = [(r, mesh) for r, mesh in zip(results, (self.ball, self.structure)) if not r.lost]
        if not bodies:
            return
        chunks = [edge_points(r.fit) if isinstance(r, OutlineResult) else mesh.effective_points[r.point_valid]
                  + r.point_u_px[r.point_valid] for r, mesh in bodies]
        now = undistort_points(self.calibration, np.concatenate(chunks))
        start = 0
        for (r, mesh), chunk in zip(bodies, chunks):
            points = now[start:start + len(chunk)]
            start += len(chunk)
            ref = self._reference_undistorted[mesh.name]
            if isinstance(r, OutlineResult):
                centre = _circle_centre(points, r.radius_px)
                if centre is not None:
                    r.u_px = centre - ref
            else:
                u = r.point_u_px[r.point_valid]
                r.u_px = r.u_px + (points - ref[r.point_valid] - u).mean(axis=0)

    def use_texture(self, texture: TextureReport) -> None:
        """Leave out the subsets the texture check found unusable (:mod:`vibro_dic.texture`)."""
        for mesh in (self.ball, self.structure):
            body = texture.bodies.get(mesh.name)
            if not isinstance(mesh, MeshTracker):
                continue  # the outline keeps every sector its own fit accepts
            if body is not None and len(body.usable) == len(mesh.points):
                mesh.subsets.textured &= body.usable

    def track(self, frame: Frame) -> FrameTrack:
        """Track one frame. ``frame.image is None`` gives lost=True and NaN displacements."""
        return self.track_image(frame.index, frame.t_s, frame.image)

    def track_image(self, index: int, t_s: float, image: np.ndarray | None) -> FrameTrack:
        """Track one image (2-D array, same size as the reference) of frame ``index`` at ``t_s`` (s)."""
        segment = index // self.reseed_every
        if segment != self._segment:
            self.ball.reseed()
            self.structure.reseed()
            self._segment = segment
        if image is None:
            self.last_results = {}
            return FrameTrack(frame=index, t_s=t_s, ball_mm=float("nan"), structure_mm=float("nan"), ball_valid=0,
                              structure_valid=0, ball_zncc=float("nan"), structure_zncc=float("nan"), lost=True)
        if image.shape != self.shape:
            raise FrameError(f"frame {index}: size {image.shape[1]}x{image.shape[0]} differs from the "
                             f"reference ({self.shape[1]}x{self.shape[0]})")
        img = image.astype(np.float32, copy=False)
        b = self.ball.track(img, index)
        s = self.structure.track(img, index)
        if self.calibration is not None:  # after the tracking: its prediction stays in the camera's pixels
            self._undistort((b, s))
        self.last_results = {"ball": b, "structure": s}
        for r in (b, s):
            if r.lost:
                log.debug("frame %d: %s", index, r.reason)
        return FrameTrack(
            frame=index, t_s=t_s,
            ball_mm=float(-b.u_px[1] * self.mm_per_px), structure_mm=float(-s.u_px[1] * self.mm_per_px),
            ball_valid=b.valid, structure_valid=s.valid, ball_zncc=b.zncc, structure_zncc=s.zncc,
            lost=bool(b.lost or s.lost), ball_rot_rad=float(b.rot_rad), ball_rot_std_rad=float(b.rot_std_rad),
        )


@dataclass(frozen=True)
class SlotNote:
    """What the tracking of one frame slot tells beside its row: the frame was unreadable (``error``) or
    dropped (no file), and the tracker's per-mesh results (``results``, {body: :class:`MeshResult`}; empty
    when the image was missing), for the correlation quality. Lets a chunk tracked elsewhere be checked,
    logged and accumulated as one pass would."""

    index: int
    ok: bool
    dropped: bool
    error: str | None
    results: dict = field(default_factory=dict)

    @classmethod
    def of(cls, frame: Frame, results: dict[str, MeshResult]) -> "SlotNote":
        return cls(frame.index, frame.ok, frame.dropped, frame.error, results)


def reference_texture(recording, *, max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX,
                      min_valid_fraction: float = 0.5, quality: TrackQuality | None = None) -> TextureReport:
    """The check before a pass over ``recording``, once per pass whoever tracks it: frame 0 (the reference)
    must decode and hold the ROIs; the texture check (:func:`vibro_dic.texture.check_texture`, noise from
    frames 0 and 1) logs its warnings and raises :class:`vibro_dic.texture.TextureError` when a body has too
    few usable subsets. The ball's tracking method (rig.yaml ``dic.ball_method``, else chosen by the texture of
    frame 0: :func:`vibro_dic.ball_method.choose_ball_method`) is logged once and checked with it. Returns the
    report (given to every tracker of the pass: :func:`track_slots`) and hands it and the choice to ``quality``."""
    rig = recording.rig
    head = list(recording.frames.iter_slots(0, 2))
    if not head:
        raise FrameError("the recording has no frame")
    first = head[0]
    if first.image is None:
        raise FrameError(f"frame {first.index} (reference): {first.error or 'cannot be read'}")
    second = head[1].image if len(head) > 1 else None
    check_rois_in_image(rig, *np.asarray(first.image).shape[:2])  # before the texture check reads the ROIs
    choice = log_ball_method(resolve_ball_method(first.image, rig.dic))
    frames = recording.frames  # the pixels' effective depth and the video's codec judge the noise estimate
    texture, warnings = check_texture(first.image, second, choice.dic, max_subset_sigma_px=max_subset_sigma_px,
                                      min_valid_fraction=min_valid_fraction,
                                      effective_bits=getattr(frames, "effective_bits", None),
                                      codec=getattr(frames, "codec", None))
    for w in warnings:
        log.warning("texture: %s", w)
    if quality is not None:
        quality.texture = texture
        quality.ball_method = choice
    return texture


def log_ball_method(choice: BallMethodChoice) -> BallMethodChoice:
    """Say once how the ball is tracked when the texture check chose it (a warning when it chose the outline:
    rig.yaml should name it); returns ``choice``."""
    if choice.source != "rig.yaml":
        (log.warning if choice.method == "outline" else log.info)("ball: %s", choice.describe())
    return choice


def track_slots(recording, start: int = 0, stop: int | None = None, *, texture: TextureReport,
                method: str = "icgn", **tracker_kwargs) -> Iterator[tuple[FrameTrack, SlotNote]]:
    """Track the frame slots ``start`` .. ``stop`` - 1 (positions; ``stop`` None: to the end) of
    ``recording`` with a new tracker on its first frame (the reference, which must decode), leaving out the
    subsets ``texture`` (:func:`reference_texture` of the same recording) found unusable.

    ``start`` must be the first slot of a tracking segment (a frame index multiple of ``reseed_every``, or
    slot 0): then the rows equal those of one pass over the whole recording (module doc, step 6).
    The unreadable-fraction check, the log lines and the correlation quality are the caller's
    (:func:`emit_rows`).
    """
    frames = recording.frames
    reference = next(iter(frames.iter_slots(0, 1)), None)
    if reference is None or reference.image is None:
        where = "0" if reference is None else reference.index
        raise FrameError(f"frame {where} (reference): {getattr(reference, 'error', None) or 'cannot be read'}")
    tracker = DicTracker.for_rig(reference.image, recording.rig, method=method, **tracker_kwargs)
    tracker.use_texture(texture)
    for frame in frames.iter_slots(start, stop):
        row = tracker.track(frame)
        yield row, SlotNote.of(frame, tracker.last_results)


def emit_rows(noted_rows: Iterable[tuple[FrameTrack, SlotNote]], guard, bar=None,
              quality: TrackQuality | None = None) -> Iterator[FrameTrack]:
    """The rows of a pass over a recording, in frame order: each slot's frame is checked by ``guard``
    (:meth:`vibro_io.frames.FrameSequence.unreadable_guard`: too many unreadable frames refuse the
    recording), a frame that could not be read is logged with its index, its results go to ``quality``
    (:class:`vibro_dic.quality.TrackQuality`, optional), then its row (lost for such a frame) is yielded."""
    for row, note in noted_rows:
        guard.check(note)
        if not note.ok:
            log.warning("frame %d skipped: %s", note.index, note.error)
        if quality is not None:
            quality.add(note.index, note.results)
        yield row
        if bar is not None:
            bar.update(1)


def track_recording(recording, *, method: str = "icgn", progress: bool = False, quality: TrackQuality | None = None,
                    max_subset_sigma_px: float = DEFAULT_MAX_SUBSET_SIGMA_PX, **tracker_kwargs
                    ) -> Iterator[FrameTrack]:
    """Stream :class:`FrameTrack` rows for every frame slot of ``recording`` (a vibro_io Recording).

    Frame 0 is the reference (it must decode). Before tracking, the texture check
    (:func:`reference_texture`: noise from frames 0 and 1) logs its warnings and raises
    :class:`vibro_dic.texture.TextureError` when a body has too few usable subsets; unusable subsets are
    left out. Frames are read one at a time; a frame that failed to decode is logged with its index and
    yields a lost row. ``quality`` (optional) receives the texture report and every frame's results
    (:class:`vibro_dic.quality.TrackQuality`). ``tracker_kwargs`` go to :class:`DicTracker`. The same
    rows and quality, tracked in chunks on Dask workers: :func:`vibro_dic.chunked.track_recording_chunked`.
    """
    from tqdm import tqdm

    texture = reference_texture(recording, max_subset_sigma_px=max_subset_sigma_px,
                                min_valid_fraction=tracker_kwargs.get("min_valid_fraction", 0.5), quality=quality)
    bar = tqdm(total=len(recording.frames), unit="frame", disable=not progress, desc="track", leave=False)
    try:
        yield from emit_rows(track_slots(recording, texture=texture, method=method, **tracker_kwargs),
                             recording.frames.unreadable_guard(), bar, quality)
    finally:
        bar.close()

