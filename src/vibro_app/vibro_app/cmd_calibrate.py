"""``vibro calibrate IMAGES... --pattern COLSxROWS --square-mm S --out camera_info.yaml``: a camera's lens
calibration from images of a checkerboard.

OpenCV's checkerboard calibration, as ROS ``camera_calibration`` runs it: the inner corners of the board found
in each image (``cv2.findChessboardCorners``, refined to sub-pixel by ``cv2.cornerSubPix``), then the camera
matrix and the plumb_bob distortion fitted to all of them (``cv2.calibrateCamera``; by default k1, k2, p1, p2
with k3 fixed at 0, ROS's default of two radial coefficients). The result is written as a ROS camera_info YAML
(:mod:`vibro_io.camera_calibration`) with its RMS reprojection error, which is printed too. Name the file in
rig.yaml's ``camera.calibration`` (and copy it into the recording): tracked positions are then undistorted
before the scale applies.

The images must be of the camera and lens setting (focus, zoom) and the image size of the recordings: the board
held at several angles and positions filling the field, above all its edges and corners, where the distortion is.
Fewer than :data:`MIN_IMAGES` images showing the whole board are refused, naming those that did not.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np

from vibro_io.camera_calibration import CameraCalibration, write_camera_info
from vibro_io.outputs import atomic_path, prepare_output_file
from vibro_model.errors import RecordingError

#: images with the board found, at least: fewer do not determine 9 parameters and their spread
MIN_IMAGES = 5


def register(sub) -> None:
    """Add the ``calibrate`` subcommand to the ``vibro`` subparsers."""
    p = sub.add_parser("calibrate", help="a camera's lens calibration (camera_info.yaml) from checkerboard images",
                       description="Find a checkerboard's inner corners in each image and fit the camera matrix "
                                   "and the plumb_bob lens distortion to them (OpenCV, as ROS camera_calibration); "
                                   "write a ROS camera_info YAML for rig.yaml's camera.calibration and print the "
                                   "RMS reprojection error.")
    p.add_argument("images", nargs="+", help="images of the board (PNG/TIFF, 8 or 16 bit, all of one size)")
    p.add_argument("--pattern", required=True, metavar="COLSxROWS",
                   help="inner corners of the board per row x per column, e.g. 9x6 for a board of 10x7 squares "
                        "(ROS camera_calibration's --size)")
    p.add_argument("--square-mm", required=True, type=float, metavar="S", help="side of one square (mm)")
    p.add_argument("--out", required=True, help="the camera_info YAML to write (refused if it exists, unless "
                                                "--overwrite)")
    p.add_argument("--radial", type=int, choices=(2, 3), default=2,
                   help="radial coefficients to fit: 2 (k1, k2; k3 fixed at 0, ROS's default) or 3")
    p.add_argument("--camera-name", default="camera", help="camera_name written to the file (default camera)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=run)


def parse_pattern(text: str) -> tuple[int, int]:
    """``COLSxROWS`` -> (cols, rows) inner corners, each >= 2."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) < 2 or int(m.group(2)) < 2:
        raise RecordingError(f"--pattern {text!r}: expected COLSxROWS, the board's inner corners per row and per "
                             "column, each at least 2 (e.g. 9x6)")
    return int(m.group(1)), int(m.group(2))


def _gray8(image: np.ndarray) -> np.ndarray:
    """An 8-bit image for the corner finder (16-bit scaled by its own range)."""
    if image.dtype == np.uint8:
        return image
    lo, hi = float(image.min()), float(image.max())
    return np.clip(np.rint((image.astype(np.float64) - lo) * (255.0 / max(hi - lo, 1.0))), 0, 255).astype(np.uint8)


def find_corners(image: np.ndarray, pattern: tuple[int, int]) -> np.ndarray | None:
    """(N, 1, 2) float32 sub-pixel inner corners of the board in ``image``, row by row, or None when the whole
    board is not found."""
    import cv2

    gray = _gray8(image)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, pattern, flags=flags)
    if not found:
        return None
    # the search window: half the smallest distance between neighbouring corners, 2..11 px
    pts = corners.reshape(-1, 2)
    grid = pts.reshape(pattern[1], pattern[0], 2)
    step = min(np.linalg.norm(np.diff(grid, axis=1), axis=2).min(), np.linalg.norm(np.diff(grid, axis=0), axis=2).min())
    half = int(np.clip(step / 2 - 1, 2, 11))
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    return cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), criteria)


def calibrate(paths: list[Path], pattern: tuple[int, int], square_mm: float, *, radial: int = 2,
              camera_name: str = "camera"):
    """The calibration (:class:`vibro_io.camera_calibration.CameraCalibration`, its RMS reprojection error set)
    from the images at ``paths``, and the images where the board was not found. Raises RecordingError naming the
    images when fewer than MIN_IMAGES show it, or an image differs in size."""
    import cv2

    from vibro_io.frames import read_image  # OpenCV: only when images are read

    cols, rows = pattern
    board = np.zeros((rows * cols, 3), np.float32)
    board[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * float(square_mm)
    size = None
    found, failed, used = [], [], []
    for path in paths:
        image = read_image(path)
        if size is None:
            size = (image.shape[1], image.shape[0])
        elif (image.shape[1], image.shape[0]) != size:
            raise RecordingError(f"{path}: {image.shape[1]}x{image.shape[0]} px, but {paths[0]} is "
                                 f"{size[0]}x{size[1]} px: calibrate with images of one size (the recordings')")
        corners = find_corners(image, pattern)
        if corners is None:
            failed.append(path)
        else:
            found.append(corners)
            used.append(path)
    if len(found) < MIN_IMAGES:
        names = ", ".join(str(p) for p in failed) or "none"
        raise RecordingError(f"the {cols}x{rows} inner-corner board was found in {len(found)} of {len(paths)} images; "
                             f"at least {MIN_IMAGES} are needed. Not found in: {names} (the whole board must be in "
                             "view and sharp; --pattern counts inner corners, e.g. 9x6 for 10x7 squares)")
    flags = 0 if radial == 3 else cv2.CALIB_FIX_K3
    rms, k, d, _, _ = cv2.calibrateCamera([board] * len(found), found, size, None, None, flags=flags)
    calib = CameraCalibration(k, np.asarray(d, dtype=np.float64).ravel()[:5], size[0], size[1],
                              camera_name=camera_name, reprojection_error_px=float(rms))
    return calib, failed, used


def run(args: argparse.Namespace) -> int:
    pattern = parse_pattern(args.pattern)
    if not args.square_mm > 0:
        raise RecordingError(f"--square-mm must be a positive length (mm), got {args.square_mm}")
    out = prepare_output_file(args.out, overwrite=args.overwrite)
    paths = [Path(p) for p in args.images]
    calib, failed, used = calibrate(paths, pattern, args.square_mm, radial=args.radial, camera_name=args.camera_name)
    for path in failed:
        print(f"warning: {path}: the {args.pattern} board was not found; image not used", file=sys.stderr)
    comment = (f"vibro calibrate: {len(used)} images, {args.pattern} inner corners, {args.square_mm:g} mm squares; "
               f"RMS reprojection error {calib.reprojection_error_px:.4f} px")
    with atomic_path(out) as tmp:
        write_camera_info(tmp, calib, comment=comment)
    print(f"calibrated from {len(used)} of {len(paths)} images: RMS reprojection error "
          f"{calib.reprojection_error_px:.4f} px")
    print(f"camera         {calib.describe()}")
    print(f"wrote {out}: name it in rig.yaml as camera.calibration (a path relative to rig.yaml, inside the "
          "recording)")
    return 0
