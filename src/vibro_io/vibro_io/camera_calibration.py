"""A camera's intrinsic calibration (lens distortion), read from and written to a ROS camera_info YAML.

rig.yaml's optional ``camera.calibration`` names the file (relative to rig.yaml, inside the recording
directory). Its format is the one ROS ``camera_calibration`` and ``camera_info_manager`` write::

    image_width: 640
    image_height: 480
    camera_name: cam1
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
    rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
    projection_matrix: {rows: 3, cols: 4, data: [...]}

OpenCV's own calibration files (``%YAML:1.0``, ``!!opencv-matrix`` with ``rows``, ``cols``, ``dt``,
``data``) are read too; there ``distortion_model`` may be absent (OpenCV's model is plumb_bob).

Pixel convention: OpenCV's, pixel centres at integer (column, row). :func:`undistort_px` maps observed
pixel positions to where an ideal pinhole camera with the same camera matrix would have seen them
(``cv2.undistortPoints`` with ``P`` = the camera matrix): the result stays in pixels of the same focal
length, so rig.yaml's ``camera.mm_per_px`` applies to it unchanged.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from vibro_model.errors import RecordingError, RigError

from .paths import inside_recording

#: the only lens model vibro undistorts with: radial k1, k2, k3 and tangential p1, p2 (Brown-Conrady)
PLUMB_BOB = "plumb_bob"
#: undistortion's fixed-point iterations stop here (px in normalized units x focal length: ~1e-9 px)
_ITER_MAX = 30
_ITER_EPS = 1e-12


class CameraInfoError(RigError):
    """A camera_info YAML that is missing, unreadable or not a usable plumb_bob calibration (a rig.yaml
    ``camera.calibration`` that cannot be used)."""


@dataclass(frozen=True, eq=False)
class CameraCalibration:
    """A camera's intrinsics: ``camera_matrix`` (3, 3) px, ``dist_coeffs`` (5,) plumb_bob [k1, k2, p1, p2, k3],
    the image size they were calibrated at (px), and where they came from (``source``, for messages).
    ``reprojection_error_px``: the calibration's RMS reprojection error when the file states it."""

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    width_px: int
    height_px: int
    camera_name: str = ""
    source: str = ""
    reprojection_error_px: float | None = None

    def __post_init__(self) -> None:
        k = np.array(self.camera_matrix, dtype=np.float64).reshape(3, 3)
        d = np.array(self.dist_coeffs, dtype=np.float64).reshape(5)
        k.setflags(write=False)
        d.setflags(write=False)
        object.__setattr__(self, "camera_matrix", k)
        object.__setattr__(self, "dist_coeffs", d)

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) px."""
        return self.width_px, self.height_px

    def same_as(self, other: "CameraCalibration", rtol: float = 1e-6, atol: float = 1e-9) -> bool:
        """Whether ``other`` is the same calibration (size, camera matrix and coefficients to ``rtol``/``atol``)."""
        return (self.image_size == other.image_size
                and np.allclose(self.camera_matrix, other.camera_matrix, rtol=rtol, atol=atol)
                and np.allclose(self.dist_coeffs, other.dist_coeffs, rtol=rtol, atol=atol))

    def check_image_size(self, width_px: int, height_px: int, what: str = "the recording's images") -> None:
        """:class:`CameraInfoError` unless the calibration was made at ``width_px`` x ``height_px``."""
        if (int(width_px), int(height_px)) != self.image_size:
            raise CameraInfoError(
                f"{self.source or 'camera calibration'}: key 'image_width'/'image_height': calibrated at "
                f"{self.width_px}x{self.height_px} px, but {what} are {width_px}x{height_px} px (a calibration "
                "holds for the sensor area and binning it was made with: calibrate the camera at this size)")

    def describe(self) -> str:
        """One line: fx, fy, cx, cy and k1, k2, p1, p2, k3."""
        k, d = self.camera_matrix, self.dist_coeffs
        return (f"fx {k[0, 0]:.2f} fy {k[1, 1]:.2f} cx {k[0, 2]:.2f} cy {k[1, 2]:.2f} px; k1 {d[0]:.5g} k2 {d[1]:.5g} "
                f"p1 {d[2]:.3g} p2 {d[3]:.3g} k3 {d[4]:.3g}")


# ------------------------------------------------------------------------------------------------ reading
class _InfoLoader(yaml.SafeLoader):
    """PyYAML with OpenCV's ``!!opencv-matrix`` tag read as a plain mapping and scientific notation as floats."""


_InfoLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", lambda loader, node: loader.construct_mapping(node,
                                                                                                             deep=True))
_InfoLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?|\.[0-9_]+(?:[eE][-+]?[0-9]+)?"
               r"|[0-9][0-9_]*[eE][-+]?[0-9]+|\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"),
    list("-+0123456789."))


def _read_mapping(path: Path) -> Mapping[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CameraInfoError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CameraInfoError(f"{path}: cannot read ({exc})") from None
    text = re.sub(r"\A%YAML:1\.0[^\n]*\n(---[^\n]*\n)?", "", text)  # OpenCV's directive, not valid YAML 1.1
    try:
        data = yaml.load(text, Loader=_InfoLoader)
    except yaml.YAMLError as exc:
        raise CameraInfoError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(data, Mapping):
        raise CameraInfoError(f"{path}: expected a camera_info mapping (image_width, camera_matrix, ...), got "
                              f"{type(data).__name__}")
    return data


def _number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def _size(data: Mapping[str, Any], key: str, src: str) -> int:
    if key not in data:
        raise CameraInfoError(f"{src}: missing required key '{key}' (pixels)")
    value = data[key]
    if not _number(value) or value != int(value) or value <= 0:
        raise CameraInfoError(f"{src}: key '{key}': expected a positive integer (pixels), got {value!r}")
    return int(value)


def _matrix(data: Mapping[str, Any], key: str, shape: tuple[int, int], src: str, *,
            required: bool = True) -> np.ndarray | None:
    """``data[key]`` as a {rows, cols, data} matrix of ``shape``, every entry a finite number."""
    if key not in data or data[key] is None:
        if required:
            raise CameraInfoError(f"{src}: missing required key '{key}' ({{rows: {shape[0]}, cols: {shape[1]}, "
                                  "data: [...]}})")
        return None
    block = data[key]
    if not isinstance(block, Mapping):
        raise CameraInfoError(f"{src}: key '{key}': expected a mapping {{rows, cols, data}}, got {block!r}")
    for name, want in (("rows", shape[0]), ("cols", shape[1])):
        if name not in block:
            raise CameraInfoError(f"{src}: missing required key '{key}.{name}' ({want})")
        if block[name] != want or isinstance(block[name], bool):
            raise CameraInfoError(f"{src}: key '{key}.{name}': expected {want}, got {block[name]!r}")
    values = block.get("data")
    n = shape[0] * shape[1]
    if not isinstance(values, (list, tuple)) or len(values) != n:
        got = f"{len(values)} values" if isinstance(values, (list, tuple)) else repr(values)
        raise CameraInfoError(f"{src}: key '{key}.data': expected a list of {n} numbers ({shape[0]}x{shape[1]}, "
                              f"row by row), got {got}")
    bad = [i for i, v in enumerate(values) if not _number(v)]
    if bad:
        raise CameraInfoError(f"{src}: key '{key}.data': entry {bad[0]} is {values[bad[0]]!r}, expected a finite "
                              "number")
    return np.array(values, dtype=np.float64).reshape(shape)


def _check_camera_matrix(k: np.ndarray, src: str) -> None:
    if not (k[0, 0] > 0 and k[1, 1] > 0):
        raise CameraInfoError(f"{src}: key 'camera_matrix.data': fx and fy (entries 0 and 4) must be positive, got "
                              f"{k[0, 0]!r} and {k[1, 1]!r} (an all-zero matrix is an uncalibrated camera)")
    if k[1, 0] != 0 or k[2, 0] != 0 or k[2, 1] != 0 or k[2, 2] != 1:
        raise CameraInfoError(f"{src}: key 'camera_matrix.data': expected [fx, s, cx, 0, fy, cy, 0, 0, 1], got "
                              f"{k.ravel().tolist()}")


def _distortion(data: Mapping[str, Any], src: str, opencv: bool) -> np.ndarray:
    model = data.get("distortion_model", PLUMB_BOB if opencv else None)
    if model is None:
        raise CameraInfoError(f"{src}: missing required key 'distortion_model' ({PLUMB_BOB})")
    if model != PLUMB_BOB:
        raise CameraInfoError(f"{src}: key 'distortion_model': {model!r} is not supported; vibro undistorts with "
                              f"'{PLUMB_BOB}' (k1 k2 p1 p2 k3: radial and tangential), the model ROS "
                              "camera_calibration and OpenCV's calibrateCamera fit by default")
    block = data.get("distortion_coefficients")
    values = block.get("data") if isinstance(block, Mapping) else None
    if opencv and isinstance(values, list) and len(values) in (4, 5) and \
            {block.get("rows"), block.get("cols")} == {1, len(values)}:
        # OpenCV writes the coefficients as a column, and k1 k2 p1 p2 alone when k3 was fixed at 0
        block = {"rows": 1, "cols": 5, "data": [*values, 0.0][:5]}
    return _matrix({"distortion_coefficients": block}, "distortion_coefficients", (1, 5), src).ravel()


def parse_camera_info(data: Any, source: str = "camera_info.yaml") -> CameraCalibration:
    """Validate a camera_info mapping (as parsed from YAML) into a :class:`CameraCalibration`; every refusal
    (:class:`CameraInfoError`) names ``source`` and the key."""
    if not isinstance(data, Mapping):
        raise CameraInfoError(f"{source}: expected a camera_info mapping, got {type(data).__name__}")
    opencv = isinstance(data.get("camera_matrix"), Mapping) and "dt" in data["camera_matrix"]
    width = _size(data, "image_width", source)
    height = _size(data, "image_height", source)
    k = _matrix(data, "camera_matrix", (3, 3), source)
    _check_camera_matrix(k, source)
    d = _distortion(data, source, opencv)
    _matrix(data, "rectification_matrix", (3, 3), source, required=False)
    _matrix(data, "projection_matrix", (3, 4), source, required=False)
    name = data.get("camera_name", "")
    rms = data.get("reprojection_error_px")
    if rms is not None and not (_number(rms) and rms >= 0):
        raise CameraInfoError(f"{source}: key 'reprojection_error_px': expected a number >= 0 (px), got {rms!r}")
    return CameraCalibration(k, d, width, height, camera_name="" if name is None else str(name), source=source,
                             reprojection_error_px=None if rms is None else float(rms))


def load_camera_info(path: str | Path, image_size: tuple[int, int] | None = None) -> CameraCalibration:
    """Read and validate a camera_info YAML (module doc). ``image_size`` (width, height) px: the recording's
    images, which the calibration must have been made at. Raises :class:`CameraInfoError` naming file and key."""
    path = Path(path)
    calib = parse_camera_info(_read_mapping(path), str(path))
    if image_size is not None:
        calib.check_image_size(*image_size)
    return calib


def calibration_from_camera_info(width: int, height: int, k: Any, d: Any, distortion_model: str,
                                 source: str = "camera_info") -> CameraCalibration | None:
    """The calibration a sensor_msgs/CameraInfo carries (``k`` its 9 values, ``d`` its coefficients), or None
    when it holds none (an uncalibrated driver publishes K all zero). A plumb_bob ``d`` of 5 values is required;
    an empty ``d`` is no distortion. Raises :class:`CameraInfoError` for anything else."""
    k = [float(v) for v in k]
    if len(k) != 9 or not any(k):
        return None
    d = [float(v) for v in d] or [0.0] * 5
    data = {"image_width": int(width), "image_height": int(height),
            "camera_matrix": {"rows": 3, "cols": 3, "data": k},
            "distortion_model": distortion_model or PLUMB_BOB,
            "distortion_coefficients": {"rows": 1, "cols": len(d), "data": d}}
    return parse_camera_info(data, source)


def calibration_of_rig(rig: Any, image_size: tuple[int, int] | None = None) -> CameraCalibration | None:
    """The calibration rig.yaml's ``camera.calibration`` names (a path relative to rig.yaml, inside the
    recording directory), read and checked against ``image_size`` (width, height) when given; None when rig.yaml
    names none. Refusals name rig.yaml and the key, and the calibration file and its key."""
    name = getattr(rig.camera, "calibration", None)
    if name is None:
        return None
    rig_path = Path(rig.path or "rig.yaml")
    where = f"{rig_path}: key 'camera.calibration'"
    try:
        path = inside_recording(rig_path.parent, name, where)
        if not path.is_file():
            raise CameraInfoError(f"{where}: {path}: file not found (the camera_info YAML of the camera's "
                                  "calibration, named relative to rig.yaml)")
        return load_camera_info(path, image_size)
    except CameraInfoError as exc:
        if str(exc).startswith(where):
            raise
        raise CameraInfoError(f"{where}: {exc}") from None
    except RecordingError as exc:  # a name leading outside the recording
        raise CameraInfoError(str(exc)) from None


# ------------------------------------------------------------------------------------------------ writing
def _scalar(text: str) -> str:
    """``text`` as a YAML scalar: plain when it reads back as itself, else double-quoted."""
    plain = re.fullmatch(r"[A-Za-z_][A-Za-z0-9_./-]*", text) and yaml.safe_load(text) == text
    return text if plain else json.dumps(text)


def _block(rows: int, cols: int, values: np.ndarray) -> str:
    data = ", ".join(repr(float(v)) for v in np.asarray(values, dtype=np.float64).ravel())
    return f"\n  rows: {rows}\n  cols: {cols}\n  data: [{data}]"


def write_camera_info(path: str | Path, calib: CameraCalibration, reprojection_error_px: float | None = None,
                      comment: str = "") -> None:
    """Write ``calib`` as a ROS camera_info YAML (module doc; rectification identity, projection [K | 0]), with
    ``reprojection_error_px`` (the RMS of the calibration, px) as an extra key ROS readers ignore and
    ``comment`` as comment lines at the top."""
    rms = calib.reprojection_error_px if reprojection_error_px is None else reprojection_error_px
    k = calib.camera_matrix
    lines = [f"# {c}" for c in comment.splitlines()]
    lines += [f"image_width: {calib.width_px}", f"image_height: {calib.height_px}",
              f"camera_name: {_scalar(calib.camera_name or 'camera')}",
              f"camera_matrix:{_block(3, 3, k)}", f"distortion_model: {PLUMB_BOB}",
              f"distortion_coefficients:{_block(1, 5, calib.dist_coeffs)}",
              f"rectification_matrix:{_block(3, 3, np.eye(3))}",
              f"projection_matrix:{_block(3, 4, np.hstack([k, np.zeros((3, 1))]))}"]
    if rms is not None:
        lines.append(f"reprojection_error_px: {float(rms)!r}")
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


# ------------------------------------------------------------------------------------------------ using
def undistort_px(calib: CameraCalibration, x_px: Any, y_px: Any) -> tuple[np.ndarray, np.ndarray]:
    """Observed pixel positions (``x_px`` columns, ``y_px`` rows; arrays of one shape, or scalars) -> where the
    ideal pinhole camera with the same camera matrix sees them (px; ``cv2.undistortPoints`` with P = the camera
    matrix, iterated to ~1e-9 px). Same shape as the input; NaN in, NaN out."""
    x, y = np.broadcast_arrays(np.asarray(x_px, dtype=np.float64), np.asarray(y_px, dtype=np.float64))
    out = undistort_points(calib, np.stack([x.ravel(), y.ravel()], axis=-1))
    return out[:, 0].reshape(x.shape), out[:, 1].reshape(y.shape)


def undistort_points(calib: CameraCalibration, points_px: np.ndarray) -> np.ndarray:
    """:func:`undistort_px` of (N, 2) (x, y) positions, as (N, 2): one OpenCV call, for a tracker's every frame."""
    import cv2  # a heavy import, only where points are undistorted

    pts = np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 1, 2)
    if pts.shape[0] == 0:
        return np.empty((0, 2))
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, _ITER_MAX, _ITER_EPS)
    k = calib.camera_matrix
    return cv2.undistortPoints(pts, k, calib.dist_coeffs, None, None, k, criteria).reshape(-1, 2)


def distort_px(calib: CameraCalibration, x_px: Any, y_px: Any) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`undistort_px`: where the lens puts the ideal pinhole image's pixel positions (the
    plumb_bob model applied in normalized coordinates, as ``cv2.projectPoints`` does)."""
    k, (k1, k2, p1, p2, k3) = calib.camera_matrix, calib.dist_coeffs
    x = np.asarray(x_px, dtype=np.float64)
    y = np.asarray(y_px, dtype=np.float64)
    yn = (y - k[1, 2]) / k[1, 1]
    xn = (x - k[0, 2] - k[0, 1] * yn) / k[0, 0]
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    return k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]


# ------------------------------------------------------------------------------------------------ in bags
#: a bag's metadata key (custom_data) holding the text of the calibration rig.yaml names, beside ``vibro.rig_yaml``
BAG_CALIBRATION_KEY = "vibro.camera_info_yaml"


def _calibration_name(rig_text: str) -> str | None:
    try:
        camera = (yaml.safe_load(rig_text) or {}).get("camera")
    except (yaml.YAMLError, AttributeError):
        return None
    name = camera.get("calibration") if isinstance(camera, Mapping) else None
    return name if isinstance(name, str) and name.strip() else None


def calibration_custom_data(rig_file: str | Path) -> dict[str, str]:
    """{:data:`BAG_CALIBRATION_KEY`: the calibration file's text} when the rig.yaml at ``rig_file`` names one
    that exists (a recorder keeps it in the bag, so that a replay undistorts alike), else {}."""
    rig_file = Path(rig_file)
    name = _calibration_name(rig_file.read_text(encoding="utf-8"))
    if name is None:
        return {}
    try:
        return {BAG_CALIBRATION_KEY: inside_recording(rig_file.parent, name, "rig.yaml").read_text(encoding="utf-8")}
    except (OSError, RecordingError):
        return {}  # the tracker reading the same rig.yaml says what is wrong with it


def write_recorded_calibration(folder: str | Path, rig_text: str, custom_data: Mapping[str, str]) -> Path | None:
    """Write the calibration a bag recorded (:func:`calibration_custom_data`) where the recorded rig.yaml, written
    to ``folder``, names it; the path written, or None when the bag holds none."""
    name = _calibration_name(rig_text)
    text = custom_data.get(BAG_CALIBRATION_KEY)
    if name is None or text is None:
        return None
    path = inside_recording(folder, name, f"{folder}/rig.yaml: key 'camera.calibration'")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path
