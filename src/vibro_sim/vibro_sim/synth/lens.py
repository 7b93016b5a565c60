"""The synthetic camera's lens: a plumb_bob radial distortion the rendered frames are seen through.

:mod:`.render` draws the ideal image, a pinhole camera's (the lab height z maps to row ``row_mid - z /
mm_per_px``). A real lens moves each point radially: the image point at normalized radius r (pixels from the
principal point over the focal length) lands at r (1 + k1 r^2 + k2 r^4). The recorded frame at pixel p_d shows
what the ideal image holds at the ideal position p_u whose distortion is p_d, i.e. p_u = undistort(p_d)
(:func:`vibro_io.camera_calibration.undistort_px`, iterated to ~1e-9 px). The frame is the ideal image
resampled there (quintic B-spline, at the exact positions; OpenCV's remap rounds them to
1/32 px), before the illumination and read noise, which the sensor adds.

The synthetic camera's matrix: fx = fy = :data:`SYNTH_FOCAL_PX` px, the principal point at the image centre
((width - 1) / 2, (height - 1) / 2). A barrel lens (k1 < 0) shrinks the scale away from the centre: along a
column through the centre the local scale at row offset dy is 1 + 3 k1 (dy / f)^2 (+ 5 k2 (dy / f)^4) of the
centre's. At the default 160 x 480 px frames the structure ROI (the lower plate) sits ~167 px below the centre,
so ``k1 = -0.18`` gives a scale ~1.5 % below the centre's there (:func:`scale_ratio`).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from vibro_io.camera_calibration import CameraCalibration, undistort_px

#: the synthetic camera's focal length (px): a 1000 px lens over a 160 x 480 px crop of the sensor
SYNTH_FOCAL_PX = 1000.0
#: the file name synth writes the calibration to (rig.yaml camera.calibration names it)
CAMERA_INFO_FILE = "camera_info.yaml"
#: |k1|, |k2| beyond these is no lens a DIC lab films through (and the undistortion's iteration may fail)
MAX_K = 2.0


def synth_calibration(width_px: int, height_px: int, k1: float, k2: float = 0.0) -> CameraCalibration:
    """The synthetic camera's calibration: fx = fy = SYNTH_FOCAL_PX, principal point at the image centre, radial
    ``k1``, ``k2`` (no tangential, no k3)."""
    k = np.array([[SYNTH_FOCAL_PX, 0.0, 0.5 * (width_px - 1)],
                  [0.0, SYNTH_FOCAL_PX, 0.5 * (height_px - 1)],
                  [0.0, 0.0, 1.0]])
    return CameraCalibration(k, [k1, k2, 0.0, 0.0, 0.0], int(width_px), int(height_px), camera_name="vibro_synth",
                             source=CAMERA_INFO_FILE)


def scale_ratio(calib: CameraCalibration, row_offset_px: float) -> float:
    """The lens's local vertical scale (d row_distorted / d row_ideal) at ``row_offset_px`` from the principal
    point along its column, over the scale at the centre (1)."""
    f = calib.camera_matrix[1, 1]
    k1, k2 = calib.dist_coeffs[:2]
    r2 = (row_offset_px / f) ** 2
    return float(1.0 + 3.0 * k1 * r2 + 5.0 * k2 * r2 * r2)


#: the edge padding scipy's map_coordinates puts around an image before its 'nearest' spline prefilter
_SPLINE_PAD = 12
_SPLINE_ORDER = 5


class Lens:
    """Resamples ideal frames as the lens of ``calib`` shows them (module doc); the sampling positions, and the
    quintic B-spline weights there, are computed once."""

    def __init__(self, calib: CameraCalibration):
        self.calib = calib
        rows, cols = np.mgrid[0:calib.height_px, 0:calib.width_px].astype(np.float64)
        x_u, y_u = undistort_px(calib, cols, rows)
        self._coords = np.stack([y_u, x_u])  # (2, H, W): rows, columns of the ideal image to sample
        self._weights = None  # the sparse resampler, built at the first frame (False: none, see _resampler)

    def _resampler(self):
        """The B-spline evaluation of ``map_coordinates(order=5, mode='nearest')`` as a sparse matrix (output
        pixel x prefiltered, padded input pixel; None where a window would leave the padding). The weights are
        separable, a row weight times a column weight, each map_coordinates' own: read off its response along
        each axis to combs of unit impulses 6 apart (each output's 6-wide window holds exactly one of a comb's)."""
        from scipy import sparse

        n = _SPLINE_ORDER + 1
        shape = (self.calib.height_px + 2 * _SPLINE_PAD, self.calib.width_px + 2 * _SPLINE_PAD)
        coords = self._coords.reshape(2, -1) + float(_SPLINE_PAD)  # as map_coordinates shifts them into the pad
        start = np.floor(coords).astype(np.int64) - _SPLINE_ORDER // 2  # each window's first row, column
        if start.min() < 0 or (start[0] + n).max() > shape[0] or (start[1] + n).max() > shape[1]:
            return None
        index, weight = [], []
        for axis in (0, 1):
            idx, w = np.empty((coords.shape[1], n), np.int64), np.empty((coords.shape[1], n))
            for a in range(n):
                comb = np.zeros(shape[axis])
                comb[a::n] = 1.0
                w[:, a] = ndimage.map_coordinates(comb, coords[axis][None, :], order=_SPLINE_ORDER, mode="nearest",
                                                  prefilter=False)
                idx[:, a] = start[axis] + (a - start[axis]) % n
            index.append(idx)
            weight.append(w)
        cols = (index[0][:, :, None] * shape[1] + index[1][:, None, :]).reshape(-1)
        data = (weight[0][:, :, None] * weight[1][:, None, :]).reshape(-1)
        indptr = np.arange(0, data.size + 1, n * n)
        return sparse.csr_array((data, cols, indptr), shape=(coords.shape[1], shape[0] * shape[1]))

    def apply(self, ideal: np.ndarray) -> np.ndarray:
        """The frame the camera records of the ideal image ``ideal`` (float, H x W): sampled at the undistorted
        position of every pixel (quintic B-spline; beyond the border the edge pixels continue). The same as
        ``map_coordinates(ideal, coords, order=5, mode='nearest')`` to float round-off (~3e-13 gray), ~3x faster: its
        prefilter, then the weights computed once (:meth:`_resampler`)."""
        ideal = np.asarray(ideal, dtype=np.float64)
        if self._weights is None:
            weights = self._resampler()
            self._weights = False if weights is None else weights
        if self._weights is False or ideal.shape != self._coords.shape[1:]:
            return ndimage.map_coordinates(ideal, self._coords, order=_SPLINE_ORDER, mode="nearest")
        padded = np.pad(ideal, _SPLINE_PAD, mode="edge")
        filtered = ndimage.spline_filter(padded, _SPLINE_ORDER, output=np.float64, mode="nearest")
        return (self._weights @ filtered.ravel()).reshape(ideal.shape)


def lens_truth(calib: CameraCalibration, calibration_file: str | None, structure_roi) -> dict:
    """The truth file's ``lens`` section: the lens the frames were seen through, the file rig.yaml names (None:
    left out, a lab that forgot to calibrate) and the scale at the structure ROI's centre over the centre's."""
    k = calib.camera_matrix
    roi_row = structure_roi.y + 0.5 * (structure_roi.h - 1)
    return {"model": "plumb_bob", "k1": float(calib.dist_coeffs[0]), "k2": float(calib.dist_coeffs[1]),
            "camera_matrix": k.tolist(), "calibration_file": calibration_file,
            "structure_roi_scale_ratio": scale_ratio(calib, roi_row - k[1, 2]),
            "convention": "frames are the ideal (pinhole) image seen through the lens: pixel p shows the ideal image "
                          "at undistort(p); frames.*_mm are true positions, what DIC measures after undistortion"}
